#pragma once
#include <array>
#include <cstdint>

#include "hal/telemetry/mavlink.h"

// Whose telemetry the mapper takes. A link may carry several systems (mavlink-router forwarding two vehicles and a
// GCS, a spoofer on the Wi-Fi): only one vehicle's autopilot may move the map. By default that is the first autopilot
// heard (a HEARTBEAT whose autopilot is not MAV_AUTOPILOT_INVALID, i.e. not a GCS, gimbal or companion), locked for
// the flight, with all its components (the vehicle's camera sends the capture messages); telemetry.system_id (and
// component_id, to take one component only) name it instead. Packets before that HEARTBEAT are not taken: an
// autopilot sends one a second, and the first sender is not to be trusted.
namespace uavm::hal::mavlink {

inline constexpr uint8_t kAutopilotInvalid = 8;  // MAV_AUTOPILOT_INVALID (common.xml)

struct SystemFilterCounters {
  int system_id = -1;     // the vehicle whose packets are taken (-1: no autopilot heard yet)
  int component_id = -1;  // its component (0: any, when only the system was configured)
  uint64_t accepted = 0;
  uint64_t foreign = 0;      // packets of other systems or components: ignored
  uint64_t before_lock = 0;  // packets before the first autopilot's HEARTBEAT: ignored
  int other_autopilots = 0;  // other systems whose HEARTBEAT says they are autopilots (each said once in the log)
};

class SystemFilter {
 public:
  // system_id 0: the first autopilot heard; component_id 0: any component of the system.
  SystemFilter(int system_id, int component_id);
  // Whether `packet` is the locked vehicle's (locking it on the first autopilot HEARTBEAT); counts the rest.
  [[nodiscard]] bool Accept(const Packet& packet);
  [[nodiscard]] const SystemFilterCounters& counters() const { return counters_; }

 private:
  void NoteHeartbeat(const Packet& packet);
  int want_system_;
  int want_component_;
  SystemFilterCounters counters_;
  std::array<bool, 256> other_autopilot_{};  // systems already said
};

}  // namespace uavm::hal::mavlink
