#pragma once
#include <nlohmann/json.hpp>
#include <string>

#include "core/pipeline/flight_session.h"
#include "core/pipeline/live_view.h"

namespace uavm {

struct FlightSummary {
  int registered = 0;  // frames of the solved component
  double residual_rms_px = 0.0;
};

// The end of the flight, in order: the flight's end noted, the live tiles' queue given up (final tiles will replace
// them), the engine's solve, the outputs (EndOfFlight, with the program's `additions`) and the journal told the flight
// finished. `live` may be null. False on a failed solve or output (message in `error`).
[[nodiscard]] bool FinishFlight(FlightSession* session, LiveView* live, OutputAdditions additions,
                                FlightSummary* summary, std::string* error);

}  // namespace uavm
