#pragma once
#include <nlohmann/json.hpp>
#include <vector>

#include "core/pipeline/flight_record.h"
#include "core/radiometry/radiometry.h"
#include "core/session/session_dir.h"

namespace uavm {

// The flight's radiometry at its end: the gains and vignetting solved over `component`'s edges from the session's
// thumbnails (thumbs/), radiometry.csv beside transforms.csv. Not ok when radiometry is off or cannot be solved.
struct EndRadiometry {
  RadiometryModel model;
  double ms = 0.0;
};
[[nodiscard]] EndRadiometry SolveEndRadiometry(const FlightRecord& record, const std::vector<int>& component,
                                               const RadiometryOptions& options, const SessionPaths& paths);
// report.json "radiometry".
[[nodiscard]] nlohmann::json RadiometryJson(const EndRadiometry& radiometry, const RadiometryOptions& options);

}  // namespace uavm
