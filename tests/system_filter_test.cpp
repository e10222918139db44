// Whose telemetry the mapper takes (hal/telemetry/system_filter.h): the first autopilot heard, or the configured one;
// another vehicle's or a GCS's packets on the same link are counted and ignored, also in a replayed log.
#include "hal/telemetry/system_filter.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "hal/telemetry/mavlink.h"
#include "hal/telemetry/telemetry_source.h"

namespace uavm::hal::mavlink {
namespace {

Packet PacketOf(const Message& m, uint8_t sysid, uint8_t compid) {
  const std::string bytes = Encode(m, 0, sysid, compid);
  Packet out;
  Parser parser;
  parser.Feed(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), [&](const Packet& p) { out = p; });
  return out;
}

const Heartbeat kAutopilot{0, 2, 3, 209, 4};  // a quadrotor, ArduPilot
const Heartbeat kGcs{0, 6, kAutopilotInvalid, 0, 4};

GlobalPositionInt Position(double lat) {
  GlobalPositionInt g;
  g.lat_deg = lat;
  g.lon_deg = 8.0;
  g.relative_alt_m = 50;
  return g;
}

TEST(SystemFilter, LocksOntoTheFirstAutopilotHeardAndCountsTheRest) {
  SystemFilter filter(0, 0);
  EXPECT_FALSE(filter.Accept(PacketOf(Position(50.0), 1, 1))) << "before any autopilot: no one is trusted";
  EXPECT_FALSE(filter.Accept(PacketOf(kGcs, 255, 190))) << "a GCS's HEARTBEAT locks nothing";
  EXPECT_EQ(filter.counters().system_id, -1);
  EXPECT_TRUE(filter.Accept(PacketOf(kAutopilot, 1, 1)));
  EXPECT_EQ(filter.counters().system_id, 1);
  EXPECT_TRUE(filter.Accept(PacketOf(Position(50.0), 1, 1)));
  EXPECT_TRUE(filter.Accept(PacketOf(Position(50.0), 1, 100))) << "the vehicle's camera component";
  // A second vehicle on the link: its HEARTBEAT is said once, its positions are ignored.
  EXPECT_FALSE(filter.Accept(PacketOf(kAutopilot, 2, 1)));
  EXPECT_FALSE(filter.Accept(PacketOf(kAutopilot, 2, 1)));
  for (int k = 0; k < 10; ++k) EXPECT_FALSE(filter.Accept(PacketOf(Position(51.0), 2, 1)));
  EXPECT_FALSE(filter.Accept(PacketOf(Position(51.0), 255, 190)));
  const SystemFilterCounters& c = filter.counters();
  EXPECT_EQ(c.accepted, 3u);
  EXPECT_EQ(c.before_lock, 2u);
  EXPECT_EQ(c.foreign, 13u);
  EXPECT_EQ(c.other_autopilots, 1);
}

TEST(SystemFilter, AConfiguredSystemAndComponentNeedNoHeartbeat) {
  SystemFilter filter(7, 1);
  EXPECT_TRUE(filter.Accept(PacketOf(Position(50.0), 7, 1)));
  EXPECT_FALSE(filter.Accept(PacketOf(Position(50.0), 7, 100))) << "another component of the configured system";
  EXPECT_FALSE(filter.Accept(PacketOf(kAutopilot, 1, 1))) << "the first autopilot is not the configured one";
  EXPECT_EQ(filter.counters().system_id, 7);
  EXPECT_EQ(filter.counters().other_autopilots, 1);
  // Only the system configured: every component of it, locked from the start.
  SystemFilter by_system(7, 0);
  EXPECT_TRUE(by_system.Accept(PacketOf(Position(50.0), 7, 100)));
}

// A replayed log of two vehicles (a router's log): frames follow the first autopilot's positions, not the second's,
// which are counted in the report.
TEST(SystemFilter, ALogOfTwoVehiclesPlacesFramesByTheFirstAutopilot) {
  const auto path =
      std::filesystem::temp_directory_path() / ("uavm_two_vehicles_" + std::to_string(getpid()) + ".tlog");
  std::string log;
  const auto record = [&](uint64_t us, const Message& m, uint8_t sysid) {
    for (int shift = 56; shift >= 0; shift -= 8) log.push_back(static_cast<char>((us >> shift) & 0xFF));
    log += Encode(m, 0, sysid, 1);
  };
  const uint64_t t0 = 1700000000000000ULL;
  record(t0, kAutopilot, 1);
  record(t0 + 1000, kAutopilot, 2);
  for (int k = 0; k < 20; ++k) {
    record(t0 + 100000ULL * k + 10, Position(50.0 + 1e-6 * k), 1);
    record(t0 + 100000ULL * k + 20, Position(10.0), 2);  // the other vehicle, far away
  }
  std::ofstream(path, std::ios::binary) << log;
  std::string error;
  auto source = MakeTelemetrySource("tlog:" + path.string(), {}, &error);
  ASSERT_NE(source, nullptr) << error;
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  const TelemetryReport r = source->Report();
  EXPECT_EQ(r.system.system_id, 1);
  EXPECT_EQ(r.system.other_autopilots, 1);
  EXPECT_EQ(r.system.foreign, 21u);
  EXPECT_EQ(r.track.fixes, 20u);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace uavm::hal::mavlink
