#pragma once
// NMEA sentences and gpsfake (Debian gpsd-clients) for the tests that drive --telemetry gpsd: through a real gpsd.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

namespace uavm::test {

// "$BODY*CS": the checksum is the XOR of the characters between '$' and '*'.
inline std::string Sentence(const std::string& body) {
  unsigned cs = 0;
  for (const char c : body) cs ^= static_cast<unsigned char>(c);
  char tail[8];
  std::snprintf(tail, sizeof(tail), "*%02X\r\n", cs);
  return "$" + body + tail;
}

// ddmm.mmmmm,H (or dddmm.mmmmm,H for longitude).
inline std::string NmeaAngle(double deg, int deg_digits, char pos, char neg) {
  const double a = std::abs(deg);
  const int whole = static_cast<int>(a);
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%0*d%08.5f,%c", deg_digits, whole, (a - whole) * 60.0, deg < 0 ? neg : pos);
  return buf;
}

// gpsfake in a process group of its own, so that killing the group takes its gpsd too. It plays a sentence every
// `cycle_s` (gpsfake -c: plus its own overhead, ~20 ms), or, `stepped`, one for each Step() (gpsfake -i: the test
// paces the log on its own clock).
class GpsFake {
 public:
  GpsFake(const std::filesystem::path& log, int port, const std::filesystem::path& out, const char* cycle_s = "0.1",
          bool stepped = false) {
    int fds[2] = {-1, -1};
    if (stepped && pipe(fds) != 0) return;
    pid_ = fork();
    if (pid_ != 0) {
      if (stepped) {
        close(fds[0]);
        step_fd_ = fds[1];
      }
      return;
    }
    setpgid(0, 0);
    if (stepped && (dup2(fds[0], STDIN_FILENO) < 0 || close(fds[1]) != 0)) _exit(126);
    const std::string p = std::to_string(port);
    if (!freopen(out.c_str(), "w", stdout) || !freopen(out.c_str(), "a", stderr)) _exit(126);
    if (stepped)
      execlp("gpsfake", "gpsfake", "-q", "-1", "-i", "-c", "0", "-P", p.c_str(), log.c_str(),
             static_cast<char*>(nullptr));
    else
      execlp("gpsfake", "gpsfake", "-q", "-1", "-c", cycle_s, "-P", p.c_str(), log.c_str(),
             static_cast<char*>(nullptr));
    _exit(127);
  }
  // Lets `sentences` more sentences go (stepped).
  bool Step(int sentences) {
    const std::string lines(static_cast<size_t>(sentences), '\n');
    return step_fd_ >= 0 && write(step_fd_, lines.data(), lines.size()) == static_cast<ssize_t>(lines.size());
  }
  ~GpsFake() { Kill(); }
  void Kill() {
    if (step_fd_ >= 0) close(step_fd_);
    step_fd_ = -1;
    if (pid_ <= 0) return;
    kill(-pid_, SIGKILL);
    kill(pid_, SIGKILL);  // in case it died before setpgid
    waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  [[nodiscard]] bool running() const { return pid_ > 0; }

 private:
  pid_t pid_ = -1;
  int step_fd_ = -1;
};

}  // namespace uavm::test
