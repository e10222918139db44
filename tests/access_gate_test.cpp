// The live server's access rules (firmware_app/access_gate.h), without a server: the token, its file, the rate limit
// and its fixed table, and which hosts count as the loopback.
#include "firmware_app/access_gate.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

namespace uavm::app {
namespace {

namespace fs = std::filesystem;
using Verdict = AccessGate::Verdict;

constexpr int64_t kSecond = 1'000'000'000;
const std::string kToken = "0123456789abcdef-token";

TEST(AccessGate, OnlyTheTokenOpensAndAMissingOneIsNoGuess) {
  AccessGate gate(kToken, {});
  EXPECT_EQ(gate.Check("10.0.0.2", kToken, 0), Verdict::kAllowed);
  EXPECT_EQ(gate.Check("10.0.0.2", std::nullopt, 0), Verdict::kUnauthorized);
  EXPECT_EQ(gate.Check("10.0.0.2", "", 0), Verdict::kUnauthorized);
  EXPECT_EQ(gate.Check("10.0.0.2", kToken + "x", 0), Verdict::kUnauthorized);          // longer
  EXPECT_EQ(gate.Check("10.0.0.2", kToken.substr(0, 10), 0), Verdict::kUnauthorized);  // a prefix
  // Requests without a token, however many, lock nobody out (a browser's first visit, a health check).
  for (int i = 0; i < 50; ++i) EXPECT_EQ(gate.Check("10.0.0.3", std::nullopt, i), Verdict::kUnauthorized);
  EXPECT_EQ(gate.Check("10.0.0.3", kToken, 100), Verdict::kAllowed);
  const auto c = gate.counters();
  EXPECT_EQ(c.allowed, 2u);
  EXPECT_EQ(c.unauthorized, 54u);
  EXPECT_EQ(c.wrong_token, 3u);
  EXPECT_EQ(c.lockouts, 0u);
}

TEST(AccessGate, WrongTokensLockTheirAddressOutForAWhileEvenWithTheRightOne) {
  AccessGate gate(kToken, {5, 60.0, 30.0});
  for (int i = 0; i < 4; ++i)
    EXPECT_EQ(gate.Check("192.168.1.9", "guess-" + std::to_string(i), i), Verdict::kUnauthorized);
  EXPECT_EQ(gate.Check("192.168.1.9", "guess-5", 10), Verdict::kUnauthorized);  // the fifth: locked from now
  EXPECT_EQ(gate.Check("192.168.1.9", kToken, 11), Verdict::kRateLimited);      // even the right token
  EXPECT_EQ(gate.RetryAfterSeconds("192.168.1.9", 11), 30);
  EXPECT_EQ(gate.Check("192.168.1.10", kToken, 12), Verdict::kAllowed);  // another address is not locked
  EXPECT_EQ(gate.Check("192.168.1.9", kToken, 10 + 30 * kSecond + 1), Verdict::kAllowed);  // the lockout is over
  // Failures further apart than the window never add up to a lockout.
  for (int i = 0; i < 10; ++i)
    EXPECT_EQ(gate.Check("192.168.1.11", "slow-guess", 100 * kSecond + i * 61 * kSecond), Verdict::kUnauthorized);
  const auto c = gate.counters();
  EXPECT_EQ(c.lockouts, 1u);
  EXPECT_EQ(c.rate_limited, 1u);
}

TEST(AccessGate, TheTableIsFixedAndAFloodOfAddressesFreesNoLockout) {
  AccessGate gate(kToken, {3, 60.0, 60.0});
  // The first address locked out, then more addresses than the table holds guess once each: the least recently seen
  // of the unlocked ones make room, the lockout stays.
  for (int i = 0; i < 3; ++i) (void)gate.Check("10.1.0.1", "guess", i);
  EXPECT_EQ(gate.Check("10.1.0.1", kToken, 10), Verdict::kRateLimited);
  for (size_t i = 0; i < 2 * AccessGate::kClients; ++i)
    EXPECT_EQ(gate.Check("10.2." + std::to_string(i / 250) + "." + std::to_string(i % 250), "guess",
                         static_cast<int64_t>(20 + i)),
              Verdict::kUnauthorized);
  EXPECT_EQ(gate.Check("10.1.0.1", kToken, 400), Verdict::kRateLimited);
  // A table full of lockouts: a new address's wrong token has no place to be counted, so it is refused as locked;
  // the right token still opens.
  AccessGate full(kToken, {1, 60.0, 60.0});
  for (size_t i = 0; i < AccessGate::kClients; ++i)
    EXPECT_EQ(full.Check("10.3.0." + std::to_string(i), "guess", 0), Verdict::kUnauthorized);
  EXPECT_EQ(full.Check("10.3.0.0", kToken, 1), Verdict::kRateLimited);
  EXPECT_EQ(full.Check("10.4.0.1", "guess", 2), Verdict::kRateLimited);
  EXPECT_EQ(full.Check("10.4.0.1", kToken, 3), Verdict::kAllowed);
  EXPECT_EQ(full.counters().lockouts, AccessGate::kClients);
}

TEST(AccessGate, AnIpv6HostIsItsSlash64) {
  EXPECT_EQ(ClientKey("192.168.1.9"), "192.168.1.9");
  EXPECT_EQ(ClientKey("::ffff:192.168.1.9"), "192.168.1.9");
  EXPECT_EQ(ClientKey("2001:db8:1:2:aaaa::1"), "2001:db8:1:2::/64");
  EXPECT_EQ(ClientKey("2001:0db8:0001:0002:ffff:1:2:3"), "2001:db8:1:2::/64");
  EXPECT_EQ(ClientKey("fe80::1"), "fe80:0:0:0::/64");
  // Guesses from many addresses of one /64 add up to one lockout.
  AccessGate gate(kToken, {3, 60.0, 60.0});
  for (int i = 0; i < 3; ++i) (void)gate.Check("2001:db8:1:2::" + std::to_string(i + 1), "guess", i);
  EXPECT_EQ(gate.Check("2001:db8:1:2:ffff::9", kToken, 10), Verdict::kRateLimited);
  EXPECT_EQ(gate.Check("2001:db8:1:3::1", kToken, 11), Verdict::kAllowed);
}

TEST(AccessGate, AStaleCookieIsNoGuess) {
  AccessGate gate(kToken, {3, 60.0, 60.0});
  for (int i = 0; i < 20; ++i)
    EXPECT_EQ(gate.Check("10.0.0.7", "old-token-0123456789", i, /*guess=*/false), Verdict::kUnauthorized);
  EXPECT_EQ(gate.Check("10.0.0.7", kToken, 100), Verdict::kAllowed);
  EXPECT_EQ(gate.counters().wrong_token, 0u);
}

TEST(AccessToken, TheFileHoldsOneUrlSafeTokenOfSixteenCharactersOrMore) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_access_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const auto write = [&](const std::string& text) {
    std::ofstream(dir / "token", std::ios::trunc) << text;
    chmod((dir / "token").c_str(), 0600);
    return (dir / "token").string();
  };
  std::string token, error;
  ASSERT_TRUE(ReadAccessToken(write("  " + kToken + "\n"), &token, &error)) << error;
  EXPECT_EQ(token, kToken);
  for (const std::string bad : {"short-token", "a token with spaces inside", "tok&en=0123456789abcdef", ""}) {
    error.clear();
    EXPECT_FALSE(ReadAccessToken(write(bad), &token, &error)) << bad;
    EXPECT_NE(error.find("openssl rand"), std::string::npos) << error;
  }
  EXPECT_FALSE(ReadAccessToken((dir / "missing").string(), &token, &error));
  fs::remove_all(dir);
}

TEST(AccessGate, LoopbackHostsAreOnlyTheLoopback) {
  for (const char* host : {"127.0.0.1", "127.1.2.3", "localhost", "::1", "[::1]"})
    EXPECT_TRUE(IsLoopbackHost(host)) << host;
  for (const char* host : {"0.0.0.0", "", "::", "192.168.1.2", "127.0.0.1.example.com", "1270.0.0.1", "my-drone.local"})
    EXPECT_FALSE(IsLoopbackHost(host)) << host;
}

}  // namespace
}  // namespace uavm::app
