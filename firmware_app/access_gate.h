#pragma once
// Who may use the live server (firmware_app/live_server.h) on a network the product does not control: a client that
// presents the access token. Independent of HTTP, so that its rules are tested without a server.
#include <array>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

namespace uavm::app {

// The token of --http-token-file: the file's text without surrounding whitespace, 16 to 256 characters a URL carries
// as they are (letters, digits, - . _ ~: `openssl rand -hex 32` makes one). False with the reason otherwise (the
// file is named: this is the operator's log, never an HTTP answer); a file others may read is said in the log.
[[nodiscard]] bool ReadAccessToken(const std::string& path, std::string* token, std::string* error);

// Whether `text` is made only of the characters a URL carries as they are (letters, digits, - . _ ~), as tokens are.
[[nodiscard]] bool IsUrlSafe(std::string_view text);

// The rate limit's key of a peer address: an IPv4 address as it is, an IPv6 address's /64 ("2001:db8:1:2::/64"; an
// IPv4-mapped one as its IPv4 address); anything else as it is.
[[nodiscard]] std::string ClientKey(std::string_view address);

// Whether HOST (of --http HOST:PORT) is a loopback address: 127.0.0.0/8, ::1 or localhost. Anything else, 0.0.0.0
// included, is reachable from a network.
[[nodiscard]] bool IsLoopbackHost(std::string_view host);

// The token check and its rate limit. The presented token is compared in constant time (the SHA-256 digests of both,
// so that neither how many bytes matched nor the token's length shows in the answer's time). Wrong tokens are
// counted per client in a fixed table (kClients): an IPv4 address, or an IPv6 address's /64 (one host has a whole
// /64 to choose from). After max_failures within window_s a client is refused for lockout_s, whatever it presents.
// A new client takes the place of the least recently seen one that is not locked out; when every place is locked
// out, a client not in the table is refused its wrong tokens as if locked (a flood of addresses cannot buy a locked
// client its way out). A request without a token is refused (401) but is no guess; neither is a stale cookie (a
// browser tab left open after the token changed polls every second): the caller says which attempts count.
class AccessGate {
 public:
  struct Options {
    int max_failures = 5;
    double window_s = 60.0;
    double lockout_s = 60.0;
  };
  enum class Verdict { kAllowed, kUnauthorized, kRateLimited };
  struct Counters {
    uint64_t allowed = 0;
    uint64_t unauthorized = 0;  // no token, or a wrong one
    uint64_t wrong_token = 0;   // of which a token was presented
    uint64_t rate_limited = 0;  // refused while the address was locked out
    uint64_t lockouts = 0;      // addresses locked out
  };
  static constexpr size_t kClients = 64;

  AccessGate(const std::string& token, Options options);
  // `client`: the peer's address; `presented`: the token the request carries (none: nullopt); `guess`: whether a wrong
  // one counts towards a lockout; `now_ns`: a monotonic clock. Thread-safe.
  [[nodiscard]] Verdict Check(std::string_view client, std::optional<std::string_view> presented, int64_t now_ns,
                              bool guess = true);
  [[nodiscard]] Counters counters() const;
  // Seconds left of `client`'s lockout (0: none), for Retry-After.
  [[nodiscard]] int RetryAfterSeconds(std::string_view client, int64_t now_ns) const;

 private:
  struct Client {
    std::array<char, 64> address{};  // the client's key (ClientKey): at most 45 characters
    size_t length = 0;
    int failures = 0;
    int64_t window_start_ns = 0;
    int64_t locked_until_ns = 0;
    int64_t last_seen_ns = 0;
  };
  [[nodiscard]] const Client* Find(std::string_view key) const;
  // The client's place, a new one if need be; null when the table is full of lockouts.
  [[nodiscard]] Client* FindOrAdd(std::string_view key, int64_t now_ns);

  std::array<uint8_t, 32> token_digest_{};
  bool token_ok_ = false;  // the token's digest was made: without it nothing is allowed
  Options options_;
  mutable std::mutex mutex_;
  std::array<Client, kClients> clients_{};
  size_t client_count_ = 0;
  Counters counters_;
};

}  // namespace uavm::app
