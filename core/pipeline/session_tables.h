#pragma once
#include <string>
#include <unordered_set>
#include <vector>

#include "core/geometry/transform.h"
#include "core/pipeline/flight_record.h"
#include "core/util/id_set.h"

namespace uavm {

// transforms.csv: every frame's canvas_from_original, whether it is in the map and what placed it (image, or
// telemetry for the frames in `by_telemetry`).
[[nodiscard]] bool WriteTransformsCsv(const std::string& path, const FlightRecord& record, const IdSet& in_map,
                                      const std::vector<Mat3>& canvas_from_original,
                                      const std::unordered_set<int>& by_telemetry, std::string* error);
// frames.csv: what the ground tool and georeferencing need per frame; empty cells where metadata is absent.
[[nodiscard]] bool WriteFramesCsv(const std::string& path, const FlightRecord& record, const IdSet& in_map,
                                  std::string* error);

}  // namespace uavm
