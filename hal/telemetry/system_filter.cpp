#include "hal/telemetry/system_filter.h"

#include <spdlog/spdlog.h>

#include <variant>

namespace uavm::hal::mavlink {

SystemFilter::SystemFilter(int system_id, int component_id) : want_system_(system_id), want_component_(component_id) {
  if (want_system_ != 0) {  // configured: no HEARTBEAT needed
    counters_.system_id = want_system_;
    counters_.component_id = want_component_;
  }
}

void SystemFilter::NoteHeartbeat(const Packet& packet) {
  const auto message = Decode(packet);
  const auto* heartbeat = message ? std::get_if<Heartbeat>(&*message) : nullptr;
  if (heartbeat == nullptr || heartbeat->autopilot == kAutopilotInvalid) return;
  if (counters_.system_id < 0) {
    if (want_component_ != 0 && packet.compid != want_component_) return;
    // Every component of the vehicle (its camera sends the capture messages), unless one was configured.
    counters_.system_id = packet.sysid;
    counters_.component_id = want_component_;
    spdlog::info("telemetry: taking system {} (the first autopilot heard: component {}, autopilot type {})",
                 packet.sysid, packet.compid, heartbeat->autopilot);
    return;
  }
  if (packet.sysid == counters_.system_id || other_autopilot_[packet.sysid]) return;
  other_autopilot_[packet.sysid] = true;
  ++counters_.other_autopilots;
  spdlog::warn(
      "telemetry: another autopilot on the link (system {} component {}): its packets are ignored; the map follows "
      "system {}",
      packet.sysid, packet.compid, counters_.system_id);
}

bool SystemFilter::Accept(const Packet& packet) {
  if (packet.msgid == kHeartbeat) NoteHeartbeat(packet);
  if (counters_.system_id < 0) {
    ++counters_.before_lock;
    return false;
  }
  if (packet.sysid != counters_.system_id || (counters_.component_id != 0 && packet.compid != counters_.component_id)) {
    ++counters_.foreign;
    return false;
  }
  ++counters_.accepted;
  return true;
}

}  // namespace uavm::hal::mavlink
