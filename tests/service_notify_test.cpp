// The onboard program as a systemd Type=notify service: a datagram socket stands in for systemd's notify socket
// (NOTIFY_SOCKET, WATCHDOG_USEC as systemd sets them), the real program runs a real flight, and the messages it sends
// are read back: READY=1 first, WATCHDOG=1 while it works, STATUS= lines with frames / registered / RSS, STOPPING=1
// before the end-of-flight work.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "tests/test_env.h"

namespace {

namespace fs = std::filesystem;

TEST(ServiceNotifyTest, ReadyWatchdogStatusAndStoppingReachTheNotifySocket) {
  const fs::path root = fs::temp_directory_path() / ("uavm_notify_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root);
  const std::string socket_path = (root / "notify.sock").string();
  const int sock = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  ASSERT_GE(sock, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  ASSERT_LT(socket_path.size(), sizeof(addr.sun_path));
  socket_path.copy(addr.sun_path, socket_path.size());
  ASSERT_EQ(::bind(sock, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)), 0);

  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::setenv("NOTIFY_SOCKET", socket_path.c_str(), 1);
    ::setenv("WATCHDOG_USEC", "2000000", 1);  // WatchdogSec=2: a ping at least every second
    const std::string log = (root / "log.txt").string();
    if (std::freopen(log.c_str(), "w", stdout) == nullptr || std::freopen(log.c_str(), "a", stderr) == nullptr)
      ::_exit(126);
    const std::string source = std::string("replay:") + UAVM_TEST_DATA + "/brighton_beach_small/images";
    const std::string out = (root / "session").string();
    std::vector<std::string> args = {UAVM_ONBOARD_BIN, "--source",     source, "--out", out,
                                     "--no-tiff",      "--max-frames", "6"};
    for (const auto& a : uavm::test::EmulationArgs()) args.push_back(a);
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  // Read while the program runs, as systemd does: a datagram socket queues only a few messages (max_dgram_qlen),
  // then the sender blocks, and a long run (under emulation) sends a watchdog ping every second.
  std::vector<std::string> messages;
  char buf[4096];
  const auto drain = [&] {
    for (;;) {
      const ssize_t n = ::recv(sock, buf, sizeof(buf), MSG_DONTWAIT);
      if (n <= 0) break;
      messages.emplace_back(buf, static_cast<size_t>(n));
    }
  };
  int status = 0;
  for (;;) {
    drain();
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    ASSERT_GE(r, 0);
    if (r == pid) break;
    ::usleep(20000);
  }
  drain();
  ::close(sock);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
  ASSERT_FALSE(messages.empty()) << "nothing reached the notify socket";
  EXPECT_NE(messages.front().find("READY=1"), std::string::npos) << messages.front();
  int watchdogs = 0;
  int statuses_with_frames = 0;
  bool stopping = false;
  for (const auto& m : messages) {
    if (m.find("WATCHDOG=1") != std::string::npos) ++watchdogs;
    if (m.find("STATUS=") != std::string::npos && m.find("registered, RSS") != std::string::npos)
      ++statuses_with_frames;
    if (m.find("STOPPING=1") != std::string::npos) stopping = true;
  }
  EXPECT_GE(watchdogs, 1);
  EXPECT_GE(statuses_with_frames, 1);
  EXPECT_TRUE(stopping);
  if (!HasFailure()) fs::remove_all(root);
}

}  // namespace
