// MAVLink 2 signing (hal/telemetry/mavlink_signing.h): the key file, the replay state's limits, and a signed .tlog.
// The signature itself is checked against node-mavlink in tests/mavlink_test.cpp (MavlinkSigningPeer).
#include "hal/telemetry/mavlink_signing.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <variant>
#include <vector>

#include "hal/telemetry/mavlink.h"
#include "hal/telemetry/telemetry_config.h"
#include "hal/telemetry/tlog.h"

namespace uavm::hal::mavlink {
namespace {

namespace fs = std::filesystem;

SigningKey TestKey(uint8_t salt = 0) {
  SigningKey key{};
  for (size_t i = 0; i < key.size(); ++i) key[i] = static_cast<uint8_t>(31 * i + 7 + salt);
  return key;
}

fs::path TempFile(const std::string& name, const std::string& bytes) {
  const fs::path p = fs::temp_directory_path() / ("uavm_signing_" + std::to_string(getpid()) + "_" + name);
  std::ofstream(p, std::ios::binary) << bytes;
  chmod(p.c_str(), 0600);
  return p;
}

std::string Position(double lat, uint8_t sysid = 1) {
  GlobalPositionInt g;
  g.lat_deg = lat;
  g.lon_deg = 8.5;
  return Encode(g, 0, sysid, 1);
}

TEST(SigningKeyFile, TakesRawBytesOrHexAndRefusesTheRest) {
  const SigningKey want = TestKey();
  std::string raw(want.begin(), want.end()), hex;
  for (uint8_t b : want) {
    static const char* kDigits = "0123456789ABCDEF";
    hex += kDigits[b >> 4];
    hex += kDigits[b & 15];
  }
  SigningKey got{};
  std::string error;
  const fs::path raw_file = TempFile("raw", raw);
  ASSERT_TRUE(ReadSigningKey(raw_file, &got, &error)) << error;
  EXPECT_EQ(got, want);
  const fs::path hex_file = TempFile("hex", "  " + hex + "\n");  // as `sha256sum | cut` writes it, upper case too
  got = {};
  ASSERT_TRUE(ReadSigningKey(hex_file, &got, &error)) << error;
  EXPECT_EQ(got, want);
  // A passphrase of 31 characters and its newline is 32 bytes, but text: not taken for a raw key.
  const std::string passphrase = "correct horse battery staple 42\n";
  ASSERT_EQ(passphrase.size(), 32u);
  for (const std::string bad :
       {raw.substr(1), hex.substr(2), hex.substr(0, 63) + "g", std::string("passphrase"), passphrase}) {
    const fs::path f = TempFile("bad", bad);
    error.clear();
    EXPECT_FALSE(ReadSigningKey(f, &got, &error)) << bad;
    EXPECT_NE(error.find("32-byte"), std::string::npos) << error;
    fs::remove(f);
  }
  EXPECT_FALSE(ReadSigningKey("/nonexistent/key", &got, &error));
  EXPECT_NE(error.find("cannot be read"), std::string::npos) << error;
  fs::remove(raw_file);
  fs::remove(hex_file);
}

TEST(SignatureCheck, SignedFramesRoundTripAndOnlyTheKeyOpensThem) {
  const SigningKey key = TestKey();
  SignatureCheck check(key);
  Parser parser;
  parser.RequireSignatures(&check);
  std::vector<double> lats;
  const auto feed = [&](const std::string& bytes) {
    parser.Feed(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), [&](const Packet& p) {
      EXPECT_TRUE(p.signed_packet);
      lats.push_back(std::get<GlobalPositionInt>(*Decode(p)).lat_deg);
    });
  };
  // One stream: the timestamps go up; a frame of another key, and one signed with ours but then altered, are refused.
  feed(Sign(Position(47.1), key, 0, 100) + Sign(Position(47.2), TestKey(1), 0, 101) +
       Sign(Position(47.3), key, 0, 102));
  std::string altered = Sign(Position(47.4), key, 0, 103);
  altered[altered.size() - 12] ^= 0x01;  // the timestamp's lowest byte (after the link id): the signature covers it
  feed(altered);
  ASSERT_EQ(lats.size(), 2u);
  EXPECT_NEAR(lats[0], 47.1, 1e-7);
  EXPECT_NEAR(lats[1], 47.3, 1e-7);
  EXPECT_EQ(check.counters().accepted, 2u);
  EXPECT_EQ(check.counters().bad_signature, 2u);
  EXPECT_EQ(parser.counters().signed_packets, 2u);
  EXPECT_EQ(parser.counters().crc_errors, 0u);  // signing recomputed the CRC over the flagged header
}

TEST(SignatureCheck, TheStreamTableIsFixedAndOldNewStreamsAreRefused) {
  const SigningKey key = TestKey();
  SignatureCheck check(key);
  const auto verdict = [&](uint8_t sysid, uint8_t link, uint64_t timestamp) {
    const std::string f = Sign(Position(10, sysid), key, link, timestamp);
    return check.Check(reinterpret_cast<const uint8_t*>(f.data()), f.size());
  };
  const uint64_t t0 = SigningTimestamp(1764504000ULL * 1000000);  // 2025-11-30
  for (size_t i = 0; i < SignatureCheck::kMaxStreams; ++i)
    EXPECT_EQ(verdict(static_cast<uint8_t>(1 + i / 4), static_cast<uint8_t>(i % 4), t0 + i),
              SignatureVerdict::kAccepted);
  // Full: a stream more is refused (counted), the known ones go on.
  EXPECT_EQ(verdict(200, 0, t0 + 100), SignatureVerdict::kNewStreamRefused);
  EXPECT_EQ(verdict(1, 0, t0 + 101), SignatureVerdict::kAccepted);
  EXPECT_EQ(verdict(1, 0, t0 + 101), SignatureVerdict::kReplayed);
  SignatureCheck fresh(key);
  const auto verdict2 = [&](uint8_t link, uint64_t timestamp) {
    const std::string f = Sign(Position(10), key, link, timestamp);
    return fresh.Check(reinterpret_cast<const uint8_t*>(f.data()), f.size());
  };
  EXPECT_EQ(verdict2(0, t0), SignatureVerdict::kAccepted);
  EXPECT_EQ(verdict2(1, t0 - kNewStreamWindow - 1), SignatureVerdict::kNewStreamRefused);  // more than a minute old
  EXPECT_EQ(verdict2(1, t0 - kNewStreamWindow + 1), SignatureVerdict::kAccepted);          // within the minute
  EXPECT_EQ(fresh.counters().new_stream_refused, 1u);
  EXPECT_EQ(SigningTimestamp(kSigningEpochUnixUs + 25), 2u);
}

TEST(SignatureCheck, ASignedLogKeepsOnlyTheVehiclesSignedRecords) {
  const SigningKey key = TestKey();
  std::string log;
  const auto record = [&log](uint64_t us, const std::string& frame) {
    for (int shift = 56; shift >= 0; shift -= 8) log.push_back(static_cast<char>((us >> shift) & 0xFF));
    log += frame;
  };
  const uint64_t us0 = 1764504000ULL * 1000000;
  for (int i = 0; i < 10; ++i) {
    const uint64_t us = us0 + 100000ULL * i;
    record(us, Sign(Position(47.0 + 0.001 * i), key, 0, SigningTimestamp(us)));
    record(us + 10, Position(46.0));                                             // unsigned: a spoofer on the link
    record(us + 20, Sign(Position(45.0), TestKey(9), 0, SigningTimestamp(us)));  // another key
  }
  record(us0 + 2000000, Sign(Position(44.0), key, 0, SigningTimestamp(us0)));  // recorded earlier, sent again
  const fs::path path = TempFile("flight.tlog", log);
  SignatureCheck check(key);
  TlogStats stats;
  std::string error;
  std::vector<double> lats;
  ASSERT_TRUE(ReadTlog(
      path, [&](uint64_t, const Packet& p) { lats.push_back(std::get<GlobalPositionInt>(*Decode(p)).lat_deg); }, &stats,
      &error, &check))
      << error;
  ASSERT_EQ(lats.size(), 10u);
  for (int i = 0; i < 10; ++i) EXPECT_NEAR(lats[i], 47.0 + 0.001 * i, 1e-7);
  EXPECT_EQ(check.counters().unsigned_refused, 10u);
  EXPECT_EQ(check.counters().bad_signature, 10u);
  EXPECT_EQ(check.counters().replayed, 1u);
  EXPECT_EQ(stats.parser.refused_by_signing, 21u);
  EXPECT_EQ(stats.resync_bytes, 0u);  // refused records are skipped whole, not taken for damage
  EXPECT_FALSE(stats.truncated);
  fs::remove(path);
}

TEST(SigningKeyFile, TheConfigKeyIsCheckedWhenTheConfigIsRead) {
  const SigningKey key = TestKey();
  const fs::path good = TempFile("config_key", std::string(key.begin(), key.end()));
  const fs::path bad = TempFile("config_bad", "a passphrase, not a key\n");
  TelemetryConfig config;
  std::string error;
  ASSERT_TRUE(
      ParseTelemetryConfigYaml("telemetry:\n  signing_key_file: " + good.string() + "\n", "test", &config, &error))
      << error;
  EXPECT_EQ(config.ToOptions().signing_key_file, good.string());
  TelemetryConfig again;
  ASSERT_TRUE(ParseTelemetryConfigYaml(ToYaml(config), "round trip", &again, &error)) << error;
  EXPECT_EQ(again.signing_key_file, good.string());
  // A file without a key is the config's error (exit 2), said before the flight, not a link that takes nothing.
  EXPECT_FALSE(
      ParseTelemetryConfigYaml("telemetry:\n  signing_key_file: " + bad.string() + "\n", "test", &config, &error));
  EXPECT_NE(error.find("32-byte"), std::string::npos) << error;
  fs::remove(good);
  fs::remove(bad);
}

}  // namespace
}  // namespace uavm::hal::mavlink
