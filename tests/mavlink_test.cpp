// The MAVLink decoder against an independent implementation: node-mavlink (npm) writes a telemetry log with known
// values (tests/telemetry/make_mavlink.mjs); we read it back whole, chunked, and damaged.
#include "hal/telemetry/mavlink.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <sstream>
#include <thread>

#include "core/util/clock.h"
#include "hal/telemetry/mavlink_signing.h"
#include "hal/telemetry/telemetry_source.h"
#include "hal/telemetry/tlog.h"
#include "tests/signing_key_util.h"
#include "tests/test_net.h"

namespace uavm::hal::mavlink {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string ReadAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void WriteAll(const fs::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary) << bytes;
}

class MavlinkTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() / ("uavm_mavlink_" + std::to_string(getpid())));
    fs::create_directories(*dir_);
    const std::string cmd = std::string("bash '") + UAVM_SOURCE_DIR + "/tests/telemetry/run_peer.sh' '" +
                            UAVM_SOURCE_DIR + "/tests/telemetry/make_mavlink.mjs' '" + dir_->string() + "'";
    peer_status_ = std::system(cmd.c_str());
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::remove_all(*dir_, ec);
    delete dir_;
  }
  void SetUp() override {
    if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "node is not installed (scripts/setup.sh)";
    ASSERT_EQ(peer_status_, 0) << "node-mavlink could not write the test log (see above)";
    tlog_ = ReadAll(*dir_ / "flight.tlog");
    expected_ = json::parse(ReadAll(*dir_ / "expected.json"));
    ASSERT_GT(tlog_.size(), 1000u);
  }

  // Reads `bytes` as a .tlog; returns the decoded messages with their arrival times.
  std::vector<std::pair<uint64_t, Message>> Read(const std::string& bytes, TlogStats* stats) const {
    const fs::path path = *dir_ / "case.tlog";
    WriteAll(path, bytes);
    std::vector<std::pair<uint64_t, Message>> out;
    std::string error;
    EXPECT_TRUE(ReadTlog(
        path.string(), [&](uint64_t us, const Packet& p) { out.emplace_back(us, *Decode(p)); }, stats, &error))
        << error;
    return out;
  }

  static fs::path* dir_;
  static int peer_status_;
  std::string tlog_;
  json expected_;
};

fs::path* MavlinkTest::dir_ = nullptr;
int MavlinkTest::peer_status_ = -1;

void ExpectNear(const json& e, const char* key, double actual) {
  if (e[key].is_null()) return;
  EXPECT_NEAR(actual, e[key].get<double>(), 1e-6 * std::max(1.0, std::abs(e[key].get<double>()))) << e.dump();
}

// Compares one decoded message with what node-mavlink was given.
void ExpectMatches(const json& e, const Message& m) {
  const auto id = e["msgid"].get<uint32_t>();
  if (id == kHeartbeat) {
    const auto& h = std::get<Heartbeat>(m);
    EXPECT_EQ(h.custom_mode, e["custom_mode"].get<uint32_t>());
    EXPECT_EQ(h.type, e["type"].get<int>());
    EXPECT_EQ(h.autopilot, e["autopilot"].get<int>());
  } else if (id == kSystemTime) {
    EXPECT_EQ(std::get<SystemTime>(m).time_unix_usec, e["time_unix_usec"].get<uint64_t>());
    EXPECT_EQ(std::get<SystemTime>(m).time_boot_ms, e["time_boot_ms"].get<uint32_t>());
  } else if (id == kGlobalPositionInt) {
    const auto& g = std::get<GlobalPositionInt>(m);
    ExpectNear(e, "lat_deg", g.lat_deg);
    ExpectNear(e, "lon_deg", g.lon_deg);
    ExpectNear(e, "alt_msl_m", g.alt_msl_m);
    ExpectNear(e, "relative_alt_m", g.relative_alt_m);
    ExpectNear(e, "vx_mps", g.vx_mps);
    ExpectNear(e, "vy_mps", g.vy_mps);
    ExpectNear(e, "vz_mps", g.vz_mps);
    EXPECT_EQ(g.heading_deg.has_value(), !e["heading_deg"].is_null());
    if (g.heading_deg) ExpectNear(e, "heading_deg", *g.heading_deg);
  } else if (id == kAttitude) {
    const auto& a = std::get<Attitude>(m);
    ExpectNear(e, "roll_rad", a.roll_rad);
    ExpectNear(e, "pitch_rad", a.pitch_rad);
    ExpectNear(e, "yaw_rad", a.yaw_rad);
  } else if (id == kGpsRawInt) {
    const auto& g = std::get<GpsRawInt>(m);
    ExpectNear(e, "lat_deg", g.lat_deg);
    ExpectNear(e, "lon_deg", g.lon_deg);
    ExpectNear(e, "alt_msl_m", g.alt_msl_m);
    EXPECT_EQ(g.fix_type, e["fix_type"].get<int>());
    EXPECT_EQ(g.satellites, e["satellites"].get<int>());
    ASSERT_TRUE(g.eph.has_value());
    ExpectNear(e, "eph", *g.eph);
    EXPECT_EQ(g.h_acc_m.has_value(), !e["h_acc_m"].is_null());  // v1 packets carry no extensions
    if (g.h_acc_m) ExpectNear(e, "h_acc_m", *g.h_acc_m);
    if (g.v_acc_m) ExpectNear(e, "v_acc_m", *g.v_acc_m);
  } else if (id == kCameraFeedback) {
    const auto& c = std::get<CameraFeedback>(m);
    ExpectNear(e, "lat_deg", c.lat_deg);
    ExpectNear(e, "alt_rel_m", c.alt_rel_m);
    ExpectNear(e, "yaw_deg", c.yaw_deg);
    ExpectNear(e, "pitch_deg", c.pitch_deg);
    EXPECT_EQ(c.image_index, e["image_index"].get<int>());
  } else if (id == kCameraImageCaptured) {
    const auto& c = std::get<CameraImageCaptured>(m);
    ExpectNear(e, "lon_deg", c.lon_deg);
    ExpectNear(e, "relative_alt_m", c.relative_alt_m);
    EXPECT_EQ(c.image_index, e["image_index"].get<int>());
    EXPECT_EQ(c.file_url, e["file_url"].get<std::string>());
    EXPECT_FLOAT_EQ(c.q[3], 0.5f);
  } else {
    ADD_FAILURE() << "unexpected message " << id;
  }
}

TEST_F(MavlinkTest, ReadsEveryMessageTheIndependentEncoderWrote) {
  TlogStats stats;
  const auto got = Read(tlog_, &stats);
  ASSERT_EQ(got.size(), expected_.size());
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].first, expected_[i]["unix_us"].get<uint64_t>());
    ExpectMatches(expected_[i], got[i].second);
  }
  EXPECT_EQ(stats.parser.crc_errors, 0u);
  EXPECT_EQ(stats.parser.unknown, 40u);  // SYS_STATUS, once per record group: framed and skipped
  EXPECT_EQ(stats.resync_bytes, 0u);
  EXPECT_FALSE(stats.truncated);
}

// Our encoder (hal/sim's telemetry, STATUSTEXT) writes back every message node-mavlink wrote: decoded, encoded and read
// again, the same values; for the messages whose fields our structs all carry, the very same payload bytes.
TEST_F(MavlinkTest, EncoderWritesBackWhatTheIndependentEncoderWrote) {
  const fs::path path = *dir_ / "encode.tlog";
  WriteAll(path, tlog_);
  std::vector<Packet> original;
  TlogStats stats;
  std::string error;
  ASSERT_TRUE(ReadTlog(
      path.string(), [&](uint64_t, const Packet& p) { original.push_back(p); }, &stats, &error));
  ASSERT_EQ(original.size(), expected_.size());
  std::string stream;
  for (const Packet& p : original) stream += Encode(*Decode(p), p.seq, p.sysid, p.compid);
  Parser parser;
  std::vector<Packet> again;
  parser.Feed(reinterpret_cast<const uint8_t*>(stream.data()), stream.size(),
              [&](const Packet& p) { again.push_back(p); });
  EXPECT_EQ(parser.counters().crc_errors, 0u);
  ASSERT_EQ(again.size(), expected_.size());
  int same_bytes = 0;
  for (size_t i = 0; i < again.size(); ++i) {
    ExpectMatches(expected_[i], *Decode(again[i]));
    const uint32_t id = again[i].msgid;
    if (id == kHeartbeat || id == kSystemTime || id == kGlobalPositionInt || id == kAttitude) {
      EXPECT_EQ(again[i].payload, original[i].payload) << "message " << id << ", record " << i;
      ++same_bytes;
    }
  }
  EXPECT_EQ(same_bytes, 160);
}

TEST_F(MavlinkTest, StreamParserGivesTheSamePacketsForAnyChunking) {
  // The same bytes without the log's timestamps, as a UDP or serial stream delivers them, fed in random pieces.
  std::string stream;
  TlogStats stats;
  const fs::path path = *dir_ / "split.tlog";
  WriteAll(path, tlog_);
  std::string error;
  ASSERT_TRUE(ReadTlog(
      path.string(),
      [&](uint64_t, const Packet& p) {
        const std::string frame = Encode(p.msgid, p.payload.data(), InfoOf(p.msgid)->length, p.seq, p.sysid, p.compid);
        stream += frame;
      },
      &stats, &error));
  std::mt19937 rng(5);
  std::uniform_int_distribution<size_t> piece(1, 90);
  Parser parser;
  std::vector<Message> got;
  for (size_t at = 0; at < stream.size();) {
    const size_t n = std::min(piece(rng), stream.size() - at);
    parser.Feed(reinterpret_cast<const uint8_t*>(stream.data() + at), n,
                [&](const Packet& p) { got.push_back(*Decode(p)); });
    at += n;
  }
  ASSERT_EQ(got.size(), expected_.size());
  for (size_t i = 0; i < got.size(); ++i) ExpectMatches(expected_[i], got[i]);
  EXPECT_EQ(parser.counters().crc_errors, 0u);
  EXPECT_EQ(parser.pending_bytes(), 0u);
}

TEST_F(MavlinkTest, GarbageAndBadChecksumsCostOnlyTheDamagedPackets) {
  std::string damaged = tlog_;
  // Flip a payload byte of the 10th record (a checksum failure) ...
  size_t record = 0, at = 0;
  for (int k = 0; k < 10; ++k) {
    record = at;
    at += 8 + FrameSize(reinterpret_cast<const uint8_t*>(damaged.data()) + at + 8);
  }
  damaged[record + 8 + 12] = static_cast<char>(damaged[record + 8 + 12] ^ 0x5A);
  // ... and put garbage full of start bytes between two later records.
  damaged.insert(at + 300, std::string("\xfd\x09\xfe\x20\x00\xfd\xff\x01garbage", 16));
  TlogStats stats;
  const auto got = Read(damaged, &stats);
  EXPECT_GE(stats.parser.crc_errors + stats.resync_bytes, 1u);
  EXPECT_GT(stats.resync_bytes, 0u);
  // Every record but the damaged one (and the one the garbage landed in, at most) is read.
  EXPECT_GE(got.size(), expected_.size() - 2);
  EXPECT_LT(got.size(), expected_.size());
}

TEST_F(MavlinkTest, TruncatedLogKeepsWhatCameBeforeTheCut) {
  TlogStats stats;
  const auto got = Read(tlog_.substr(0, tlog_.size() / 2 + 7), &stats);
  EXPECT_TRUE(stats.truncated);
  EXPECT_GT(got.size(), expected_.size() / 2 - 10);
  EXPECT_LT(got.size(), expected_.size() / 2 + 10);
  for (size_t i = 0; i < got.size(); ++i) ExpectMatches(expected_[i], got[i].second);
}

std::string PeerCommand(const std::string& script, const std::string& args) {
  return std::string("bash '") + UAVM_SOURCE_DIR + "/tests/telemetry/run_peer.sh' '" + UAVM_SOURCE_DIR +
         "/tests/telemetry/" + script + "' " + args;
}

TEST_F(MavlinkTest, ReplayedStillsTakeTheCameraTriggersInSequence) {
  std::string error;
  auto source = MakeTelemetrySource("tlog:" + (*dir_ / "flight.tlog").string(), {}, &error);
  ASSERT_NE(source, nullptr) << error;
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  std::vector<json> triggers;
  for (const auto& e : expected_)
    if (e["msgid"].get<uint32_t>() == kCameraFeedback) triggers.push_back(e);
  ASSERT_EQ(triggers.size(), 8u);
  Frame frame;
  for (size_t k = 0; k < triggers.size(); ++k) {
    frame.index = k;  // the k-th file of the replay takes the k-th trigger (image numbers from the first one)
    const auto pose = source->PoseFor(frame);
    ASSERT_TRUE(pose.has_value());
    EXPECT_NEAR(pose->lat_deg, triggers[k]["lat_deg"].get<double>(), 1e-9);
    EXPECT_NEAR(*pose->relative_alt_m, 80.25, 1e-6);
    EXPECT_NEAR(*pose->yaw_deg, 271.25, 1e-6);
  }
  frame.index = triggers.size();
  EXPECT_FALSE(source->PoseFor(frame).has_value());  // a ninth frame: no trigger left
  const TelemetryReport r = source->Report();
  EXPECT_EQ(r.match, "sequence");
  EXPECT_EQ(r.triggers, 8u);
  EXPECT_EQ(r.triggers_missing, 1u);
  EXPECT_EQ(r.frames_placed, 8u);
  EXPECT_EQ(r.frames_without, 1u);
}

TEST_F(MavlinkTest, ReplayedStillsWithoutTriggersMatchByExifTime) {
  const fs::path dir = *dir_ / "nocam";
  ASSERT_EQ(std::system(PeerCommand("make_mavlink.mjs", "'" + dir.string() + "' --no-camera").c_str()), 0);
  TelemetryOptions options;
  options.exif_utc_offset_s = 3600;  // the camera's clock on CET
  std::string error;
  auto source = MakeTelemetrySource("tlog:" + (dir / "flight.tlog").string(), options, &error);
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  Frame frame;
  // 1700000002 s UTC = 2023-11-14 22:13:22 UTC = 23:13:22 CET: record 10 of the log (0.2 s apart).
  frame.metadata.datetime_original = "2023:11:14 23:13:22";
  const auto pose = source->PoseFor(frame);
  ASSERT_TRUE(pose.has_value());
  EXPECT_NEAR(pose->lat_deg, (501234567 + 10 * 91) * 1e-7, 1e-9);
  EXPECT_NEAR(*pose->relative_alt_m, 80.1, 1e-9);
  // A frame of another flight (a day later): refused, said so.
  frame.metadata.datetime_original = "2023:11:15 23:13:22";
  EXPECT_FALSE(source->PoseFor(frame).has_value());
  EXPECT_FALSE(source->Report().log_overlaps_frames);
  EXPECT_EQ(source->Report().match, "time");
}

TEST_F(MavlinkTest, LiveUdpLinkPlacesFramesAndLosingItIsCounted) {
  const int port = test::FreePort(SOCK_DGRAM);
  ASSERT_GT(port, 0);
  std::string error;
  auto source = MakeTelemetrySource("mavlink-udp:127.0.0.1:" + std::to_string(port), {}, &error);
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  // 3 s of 20 Hz telemetry from the independent encoder, in the background; node may take a while to start on a
  // loaded machine, so the frame is taken once fixes flow.
  std::string heard;  // what the ground station's side printed: the STATUSTEXTs it decoded
  std::thread sender([&] {
    FILE* out = popen(PeerCommand("send_udp.mjs", std::to_string(port) + " 3 20").c_str(), "r");
    if (out == nullptr) return;
    char buf[256];
    while (std::fgets(buf, sizeof(buf), out) != nullptr) heard += buf;
    pclose(out);
  });
  for (int waited = 0; source->Report().parser.packets < 10 && waited < 300; ++waited)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  source->SendStatus("uavm: 12 frames, 11 registered");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  Frame frame;
  frame.timestamp_ns = MonotonicNs() - 100'000'000;
  const auto pose = source->PoseFor(frame);
  sender.join();
  ASSERT_TRUE(pose.has_value()) << "no telemetry arrived";
  EXPECT_NE(heard.find("STATUSTEXT uavm: 12 frames, 11 registered"), std::string::npos) << heard;
  EXPECT_GT(pose->lat_deg, 50.0);
  EXPECT_LT(pose->lat_deg, 50.0 + 61e-6);
  EXPECT_NEAR(pose->lon_deg, 8.0, 1e-9);
  EXPECT_NEAR(*pose->relative_alt_m, 90.0, 1e-9);
  EXPECT_NEAR(*pose->yaw_deg, 90.0, 1e-4);
  // The link goes quiet: a frame 2.5 s later gets no pose (stale), counted, never a silent old position.
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));
  frame.timestamp_ns = MonotonicNs();
  EXPECT_FALSE(source->PoseFor(frame).has_value());
  const TelemetryReport r = source->Report();
  EXPECT_EQ(r.frames_placed, 1u);
  EXPECT_EQ(r.frames_without, 1u);
  EXPECT_GT(r.parser.packets, 100u);
  EXPECT_EQ(r.parser.crc_errors, 0u);
  source->Stop();
}

// A log of the MAVLink camera protocol (CAMERA_IMAGE_CAPTURED, no CAMERA_FEEDBACK): frames take the capture of their
// image number; a failed capture (capture_result 0) and a capture without a position (lat = lon = 0) place nothing,
// and the frames after them keep their own captures. The yaw comes from the camera's attitude quaternion.
TEST(MavlinkTriggers, ImageCapturedMatchesByImageNumber) {
  const fs::path path = fs::temp_directory_path() / ("uavm_captured_" + std::to_string(getpid()) + ".tlog");
  std::string log;
  const double yaw = 30.0 * M_PI / 180.0;  // about NED down: q = (cos(yaw/2), 0, 0, sin(yaw/2))
  uint8_t seq = 0;
  // The autopilot's HEARTBEAT (system 1): the camera component of the same vehicle sends the captures.
  for (int shift = 56; shift >= 0; shift -= 8) log.push_back(static_cast<char>((1700000000000000ULL >> shift) & 0xFF));
  log += Encode(Heartbeat{0, 2, 3, 209, 4}, seq++, 1, 1);
  for (int32_t i = 1; i <= 6; ++i) {
    CameraImageCaptured c;
    c.time_utc_usec = 1700000000000000ULL + static_cast<uint64_t>(i) * 2000000ULL;
    c.lat_deg = i == 4 ? 0.0 : 46.0 + i * 1e-4;
    c.lon_deg = i == 4 ? 0.0 : 7.0;
    c.relative_alt_m = 60;
    c.q = {static_cast<float>(std::cos(yaw / 2)), 0.f, 0.f, static_cast<float>(std::sin(yaw / 2))};
    c.image_index = 100 + i;            // the camera had counted 100 images before this flight
    c.capture_result = i == 2 ? 0 : 1;  // image 102 failed: no file, no trigger
    const uint64_t us = c.time_utc_usec;
    for (int shift = 56; shift >= 0; shift -= 8) log.push_back(static_cast<char>((us >> shift) & 0xFF));
    log += Encode(c, seq++, 1, 100);
  }
  std::ofstream(path, std::ios::binary) << log;
  std::string error;
  auto source = MakeTelemetrySource("tlog:" + path.string(), {}, &error);
  ASSERT_NE(source, nullptr) << error;
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  Frame frame;
  std::vector<bool> placed;
  for (uint64_t i = 0; i < 6; ++i) {
    frame.index = i;  // image 101 + i
    const auto pose = source->PoseFor(frame);
    placed.push_back(pose.has_value());
    if (!pose) continue;
    EXPECT_NEAR(pose->lat_deg, 46.0 + static_cast<double>(i + 1) * 1e-4, 1e-7) << "frame " << i;
    ASSERT_TRUE(pose->yaw_deg.has_value());
    EXPECT_NEAR(*pose->yaw_deg, 30.0, 1e-4);
  }
  EXPECT_EQ(placed, (std::vector<bool>{true, false, true, false, true, true}));
  const TelemetryReport r = source->Report();
  EXPECT_EQ(r.match, "sequence");
  EXPECT_EQ(r.triggers, 5u);
  EXPECT_EQ(r.triggers_missing, 1u);
  EXPECT_EQ(r.triggers_without_fix, 1u);
  fs::remove(path);
}

TEST(MavlinkFraming, SignedPacketsAreAcceptedAndUnknownFlagsDropped) {
  std::string frame = Encode(Statustext{6, "mapper: 12 frames"}, 3, 1, 191);
  // Sign it: incompatibility flag 0x01 (in the CRC), 13 signature bytes after the CRC (not checked here).
  frame[2] = 0x01;
  const uint16_t crc = Crc(&InfoOf(kStatustext)->crc_extra, 1,
                           Crc(reinterpret_cast<const uint8_t*>(frame.data()) + 1, frame.size() - 3));
  frame[frame.size() - 2] = static_cast<char>(crc & 0xFF);
  frame[frame.size() - 1] = static_cast<char>(crc >> 8);
  frame += std::string(13, '\x42');
  std::string unknown_flag = Encode(Statustext{4, "x"}, 4, 1, 191);
  unknown_flag[2] = 0x04;
  Parser parser;
  std::vector<Statustext> got;
  const std::string bytes = frame + unknown_flag + Encode(Statustext{2, "after"}, 5, 1, 191);
  parser.Feed(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(),
              [&](const Packet& p) { got.push_back(std::get<Statustext>(*Decode(p))); });
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[0].text, "mapper: 12 frames");
  EXPECT_EQ(got[1].text, "after");
  EXPECT_EQ(parser.counters().signed_packets, 1u);
  EXPECT_EQ(parser.counters().unsupported, 1u);
}

// MAVLink 2 signing against node-mavlink's signer (Node's crypto SHA-256, tests/telemetry/signing_peer.mjs): its
// check finds the signatures we make right (and one made with another key wrong), and each datagram it signs gets
// the verdict the spec asks for from our receiver: taken, unsigned, another key, replayed, a new stream too old, cut
// short, one bit of the signature flipped.
TEST(MavlinkSigningPeer, SignaturesAgreeWithNodeMavlink) {
  if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "node is not installed (scripts/setup.sh)";
  const fs::path dir = fs::temp_directory_path() / ("uavm_signing_" + std::to_string(getpid()));
  fs::create_directories(dir);
  SigningKey key{}, other{};
  for (size_t i = 0; i < key.size(); ++i) {
    key[i] = static_cast<uint8_t>(17 * i + 3);
    other[i] = static_cast<uint8_t>(key[i] ^ 0x80);
  }
  WriteAll(dir / "key.hex", test::HexKeyFileText(key));
  std::string ours;
  const auto add = [&ours](const std::string& frame) {
    ours += std::string{static_cast<char>(frame.size() & 0xFF), static_cast<char>(frame.size() >> 8)} + frame;
  };
  for (int k = 0; k < 5; ++k) {
    GlobalPositionInt g;
    g.lat_deg = 14.6 + 1e-5 * k;
    g.lon_deg = -91.99;
    add(Sign(Encode(g, static_cast<uint8_t>(k), 1, 1), key, static_cast<uint8_t>(k % 2), 1000000 + k));
  }
  add(Sign(Encode(Heartbeat{0, 2, 3, 209, 4}, 9, 1, 1), other, 0, 2000000));  // another key
  add(Sign(Encode(Statustext{6, "mapper: 12 frames"}, 10, 1, 191), key, 0, 2000001));
  WriteAll(dir / "ours.bin", ours);
  ASSERT_EQ(std::system(PeerCommand("signing_peer.mjs", "'" + dir.string() + "'").c_str()), 0);
  EXPECT_EQ(json::parse(ReadAll(dir / "ours.json")), json::parse("[true,true,true,true,true,false,true]"));

  const std::string theirs = ReadAll(dir / "theirs.bin");
  const json expected = json::parse(ReadAll(dir / "theirs.json"));
  SignatureCheck check(key);
  Parser parser;
  parser.RequireSignatures(&check);
  size_t at = 0, n = 0;
  for (; at + 2 <= theirs.size(); ++n) {
    const size_t size = static_cast<uint8_t>(theirs[at]) | (static_cast<uint8_t>(theirs[at + 1]) << 8);
    const SigningCounters before = check.counters();
    const uint64_t cut_before = parser.counters().cut_short;
    std::optional<double> lat;
    parser.Feed(reinterpret_cast<const uint8_t*>(theirs.data() + at + 2), size, [&](const Packet& p) {
      if (const auto m = Decode(p); m && std::holds_alternative<GlobalPositionInt>(*m))
        lat = std::get<GlobalPositionInt>(*m).lat_deg;
      else
        lat = 0;  // taken, not a position (the HEARTBEAT)
    });
    parser.EndDatagram();  // as the UDP link does after each datagram
    at += 2 + size;
    const SigningCounters& after = check.counters();
    const std::string verdict = lat                                                    ? "accepted"
                                : parser.counters().cut_short > cut_before             ? "cut_short"
                                : after.unsigned_refused > before.unsigned_refused     ? "unsigned"
                                : after.bad_signature > before.bad_signature           ? "bad_signature"
                                : after.replayed > before.replayed                     ? "replayed"
                                : after.new_stream_refused > before.new_stream_refused ? "new_stream_refused"
                                                                                       : "nothing";
    ASSERT_LT(n, expected.size());
    EXPECT_EQ(verdict, expected[n]["verdict"].get<std::string>()) << "datagram " << n;
    if (lat && !expected[n]["lat"].is_null()) EXPECT_NEAR(*lat, expected[n]["lat"].get<double>() * 1e-7, 1e-9) << n;
  }
  EXPECT_EQ(n, expected.size());
  EXPECT_EQ(check.counters().accepted, 5u);
  EXPECT_EQ(check.counters().unsigned_refused, 2u);
  EXPECT_EQ(check.counters().bad_signature, 2u);
  EXPECT_EQ(check.counters().replayed, 2u);
  EXPECT_EQ(check.counters().new_stream_refused, 1u);
  EXPECT_EQ(parser.counters().cut_short, 1u);
  EXPECT_EQ(parser.counters().refused_by_signing, 7u);
  std::error_code ec;
  fs::remove_all(dir, ec);
}

TEST(MavlinkFraming, CrcMatchesTheStandardCheckValue) {
  // CRC-16/MCRF4XX of "123456789" is 0x6F91 (the catalogue's check value).
  const std::string s = "123456789";
  EXPECT_EQ(Crc(reinterpret_cast<const uint8_t*>(s.data()), s.size()), 0x6F91);
}

}  // namespace
}  // namespace uavm::hal::mavlink
