#pragma once
// A loopback port nobody holds, chosen by the kernel (bind to port 0), for tests that start a server or a listener.
// Fixed or pid-derived ports collide with whatever else the parallel suite (or the machine) has open.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

namespace uavm::test {

// SOCK_STREAM for TCP servers (HTTP, gpsd), SOCK_DGRAM for UDP listeners (MAVLink).
inline int FreePort(int socket_type = SOCK_STREAM) {
  const int fd = ::socket(AF_INET, socket_type, 0);
  if (fd < 0) return -1;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof(a);
  const bool ok = ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0 &&
                  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0;
  ::close(fd);
  return ok ? ntohs(a.sin_port) : -1;
}

}  // namespace uavm::test
