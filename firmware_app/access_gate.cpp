#include "firmware_app/access_gate.h"

#include <arpa/inet.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>

namespace uavm::app {

namespace {

constexpr size_t kMinToken = 16, kMaxToken = 256;

// SHA-256 of `text`; false when OpenSSL could not make it (no memory), and then nothing may match.
bool Sha256(std::string_view text, std::array<uint8_t, 32>* digest) {
  unsigned int size = 0;
  return EVP_Digest(text.data(), text.size(), digest->data(), &size, EVP_sha256(), nullptr) == 1 && size == 32;
}

bool UrlSafeChar(char c) {
  return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '.' || c == '_' || c == '~';
}

int64_t Ns(double seconds) {
  return static_cast<int64_t>(std::llround(seconds * 1e9));
}

}  // namespace

bool ReadAccessToken(const std::string& path, std::string* token, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "--http-token-file " + path + " cannot be read";
    return false;
  }
  std::string text(kMaxToken + 64, '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<size_t>(in.gcount()));
  const auto space = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
  while (!text.empty() && space(text.back())) text.pop_back();
  text.erase(text.begin(), std::find_if_not(text.begin(), text.end(), space));
  if (text.size() < kMinToken || text.size() > kMaxToken || !IsUrlSafe(text)) {
    *error = "--http-token-file " + path + " must hold one token of 16 to 256 letters, digits, '-', '.', '_' or '~' " +
             "(e.g. `openssl rand -hex 32 > " + path + "`)";
    return false;
  }
  struct stat st {};
  if (stat(path.c_str(), &st) == 0 && (st.st_mode & 077) != 0)
    spdlog::warn("--http-token-file {} can be read by other users (mode {:o}): chmod 600 it", path, st.st_mode & 0777);
  *token = text;
  return true;
}

bool IsUrlSafe(std::string_view text) {
  return std::all_of(text.begin(), text.end(), UrlSafeChar);
}

std::string ClientKey(std::string_view address) {
  const std::string text(address);
  in6_addr v6{};
  if (text.find(':') == std::string::npos || inet_pton(AF_INET6, text.c_str(), &v6) != 1) return text;
  const uint8_t* b = v6.s6_addr;
  static constexpr uint8_t kMapped[12] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xFF, 0xFF};
  char out[64];
  if (std::equal(b, b + 12, kMapped)) {
    std::snprintf(out, sizeof(out), "%u.%u.%u.%u", b[12], b[13], b[14], b[15]);
  } else {
    std::snprintf(out, sizeof(out), "%x:%x:%x:%x::/64", (b[0] << 8) | b[1], (b[2] << 8) | b[3], (b[4] << 8) | b[5],
                  (b[6] << 8) | b[7]);
  }
  return out;
}

bool IsLoopbackHost(std::string_view host) {
  if (host == "localhost" || host == "::1" || host == "[::1]") return true;
  if (host.substr(0, 4) != "127.") return false;
  int dots = 0;  // a dotted quad in 127.0.0.0/8, not a name that starts with "127."
  for (char c : host) {
    if (c == '.')
      ++dots;
    else if (!std::isdigit(static_cast<unsigned char>(c)))
      return false;
  }
  return dots == 3;
}

AccessGate::AccessGate(const std::string& token, Options options)
    : token_ok_(Sha256(token, &token_digest_)), options_(options) {}

const AccessGate::Client* AccessGate::Find(std::string_view key) const {
  for (size_t i = 0; i < client_count_; ++i)
    if (std::string_view(clients_[i].address.data(), clients_[i].length) == key) return &clients_[i];
  return nullptr;
}

AccessGate::Client* AccessGate::FindOrAdd(std::string_view key, int64_t now_ns) {
  if (const Client* c = Find(key)) return const_cast<Client*>(c);
  Client* slot = nullptr;
  if (client_count_ < clients_.size()) {
    slot = &clients_[client_count_++];
  } else {  // full: forget the least recently seen client that is not locked out
    for (Client& c : clients_)
      if (c.locked_until_ns <= now_ns && (slot == nullptr || c.last_seen_ns < slot->last_seen_ns)) slot = &c;
    if (slot == nullptr) return nullptr;
  }
  *slot = Client{};
  slot->length = std::min(key.size(), slot->address.size());
  std::copy_n(key.begin(), slot->length, slot->address.begin());
  slot->window_start_ns = now_ns;
  return slot;
}

AccessGate::Verdict AccessGate::Check(std::string_view address, std::optional<std::string_view> presented,
                                      int64_t now_ns, bool guess) {
  std::array<uint8_t, 32> digest{};
  const bool right = token_ok_ && presented && Sha256(*presented, &digest) &&
                     CRYPTO_memcmp(digest.data(), token_digest_.data(), digest.size()) == 0;
  const std::string client = ClientKey(address);
  std::lock_guard lock(mutex_);
  const Client* known = Find(client);
  if (known != nullptr && known->locked_until_ns > now_ns) {
    const_cast<Client*>(known)->last_seen_ns = now_ns;
    ++counters_.rate_limited;
    return Verdict::kRateLimited;
  }
  if (right) {
    ++counters_.allowed;
    return Verdict::kAllowed;
  }
  ++counters_.unauthorized;
  if (!presented || !guess) return Verdict::kUnauthorized;
  ++counters_.wrong_token;
  Client* c = FindOrAdd(client, now_ns);
  if (c == nullptr) {  // every place holds a lockout: no room to count this one, so it is refused as one
    ++counters_.rate_limited;
    return Verdict::kRateLimited;
  }
  c->last_seen_ns = now_ns;
  if (now_ns - c->window_start_ns > Ns(options_.window_s)) {
    c->window_start_ns = now_ns;
    c->failures = 0;
  }
  if (++c->failures >= options_.max_failures) {
    c->locked_until_ns = now_ns + Ns(options_.lockout_s);
    c->failures = 0;
    c->window_start_ns = c->locked_until_ns;
    ++counters_.lockouts;
    spdlog::warn("live view: {} wrong access tokens from {} within {} s: it is refused for {} s", options_.max_failures,
                 client, options_.window_s, options_.lockout_s);
  }
  return Verdict::kUnauthorized;
}

AccessGate::Counters AccessGate::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

int AccessGate::RetryAfterSeconds(std::string_view address, int64_t now_ns) const {
  const std::string client = ClientKey(address);
  std::lock_guard lock(mutex_);
  const Client* c = Find(client);
  if (c == nullptr || c->locked_until_ns <= now_ns) return 0;
  return static_cast<int>((c->locked_until_ns - now_ns + 999'999'999) / 1'000'000'000);
}

}  // namespace uavm::app
