#pragma once
#include <cstdint>
#include <functional>
#include <string>

#include "hal/telemetry/mavlink.h"

namespace uavm::hal::mavlink {

// What reading a .tlog met: the operator sees it in the log and report.json, never a silent gap.
struct TlogStats {
  uint64_t records = 0;       // packets delivered (known messages)
  uint64_t resync_bytes = 0;  // bytes skipped to find the next plausible record after damage
  bool truncated = false;     // the file ends inside a record
  ParserCounters parser;      // CRC errors, unknown messages, signed packets
};

// Reads a MAVLink telemetry log as QGroundControl and MAVProxy write it: each packet preceded by its arrival time, an
// 8-byte big-endian count of microseconds since the UNIX epoch. Streams the file through a fixed buffer; damage
// (garbage, a bad CRC, a cut-off end) skips to the next plausible record (a start byte after a timestamp close to the
// last good one). Calls on_packet(unix_us, packet) for each known message. False only when the file cannot be read.
// With `signatures` (borrowed; null: not checked) only frames it accepts are delivered, as on a live link; a record
// it refuses is skipped whole, as a record, not as damage.
[[nodiscard]] bool ReadTlog(const std::string& path,
                            const std::function<void(uint64_t unix_us, const Packet& packet)>& on_packet,
                            TlogStats* stats, std::string* error, SignatureCheck* signatures = nullptr);

}  // namespace uavm::hal::mavlink
