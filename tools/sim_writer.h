#pragma once
#include <string>

#include "hal/sim/sim_source.h"

namespace uavm::tools {

// Writes a simulated flight so it can be replayed (`--source replay:OUT/images`) and evaluated later:
//   OUT/images/frame_000000.jpg ...  (.png when the plan has no JPEG round trip; JPEG files hold exactly the bytes
//                                     the source decoded, so replayed frames equal the emitted ones)
//   OUT/gt.csv                        ground truth (core/eval/ground_truth.h)
//   OUT/gt_camera.yaml                the camera's truth: lens distortion and vignetting (core/eval/ground_truth.h)
//   OUT/gt_exposure.csv               each frame's exposure gain, offset and white balance (same)
//   OUT/plan.yaml                     the effective plan, canvas path made absolute
//   OUT/geo.txt, OUT/geo_truth.txt    with the plan's gps: each frame's reported and true position (OpenDroneMap
//                                     geo.txt, EPSG:4326), for --telemetry geo: and for measuring against the truth
//   OUT/flight.tlog                   with the plan's gps: the flight controller's MAVLink telemetry of the flight
//                                     (hal/sim/sim_telemetry.h), for --telemetry tlog: (frames matched by trigger)
// `source` must be open; it is consumed from its current position. max_frames 0 = all.
// In tools/, not hal/sim: it writes the evaluator's format (core/eval), which the onboard program must not link.
[[nodiscard]] bool WriteSimFlight(hal::SimSource* source, const std::string& out_dir, int max_frames,
                                  std::string* error);

}  // namespace uavm::tools
