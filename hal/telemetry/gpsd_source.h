#pragma once
#include <memory>
#include <string>

#include "hal/telemetry/telemetry_source.h"

namespace uavm::hal {

// --telemetry gpsd:HOST:PORT: a GNSS receiver without a flight controller, read through gpsd (libgps). A thread
// watches the daemon's TPV reports and stamps each fix with the monotonic clock on arrival (the frames' clock, as the
// MAVLink links do; telemetry.latency_ms covers the receiver-to-gpsd delay). Height above take-off is measured from
// the first 3-D fix's altitude; the course over ground stands for the heading while the vehicle moves. A lost daemon
// is logged, counted (TelemetryReport::link_losses) and reconnected to a bounded number of times; frames go on
// image-only meanwhile. Only built with libgps (UAVM_WITH_GPSD).
[[nodiscard]] std::unique_ptr<TelemetrySource> MakeGpsdSource(const std::string& host, int port,
                                                              const TelemetryOptions& options);

}  // namespace uavm::hal
