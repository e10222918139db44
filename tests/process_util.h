#pragma once
// Running programs from tests: a background child (the onboard program with its live server) and a command's output
// (gdal_translate, gdalinfo).
#include <sys/types.h>
#include <unistd.h>

#include <cstdio>
#include <string>

namespace uavm::test {

// `cmd` through /bin/sh, not waited for; the caller waitpid()s (or kills) the returned pid.
inline pid_t Spawn(const std::string& cmd) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::execl("/bin/sh", "sh", "-c", ("exec " + cmd).c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  return pid;
}

// What `cmd` printed on stdout (append 2>&1 for stderr too).
inline std::string CommandOutput(const std::string& cmd) {
  std::string out;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) return out;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof(buf), p)) > 0;) out.append(buf, n);
  ::pclose(p);
  return out;
}

}  // namespace uavm::test
