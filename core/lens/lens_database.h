#pragma once
// Lens distortion from a camera database: lensfun (Debian's liblensfun-dev and liblensfun-data-v1), when EXIF names a
// camera it knows. Built only where lensfun is found (UAVM_WITH_LENSFUN); elsewhere every lookup says so.
#include <string>
#include <utility>
#include <vector>

#include "core/geometry/camera_model.h"

namespace uavm {

struct LensDatabaseEntry {
  std::string camera;  // the database's names
  std::string lens;
  double crop_factor = 0.0;
  LensDistortion distortion;  // Brown (k1, k2) in the normalised coordinates of the camera it was looked up for
  double centre_scale = 1.0;  // the database's ideal image against ours, at the centre (taken out of the fit)
  // The database calibrated the lens on raw files (lensfun names such entries, e.g. "with CHDK's DNG"): it describes
  // the sensor's data, not a camera's processed frames, which its own processing may already have corrected.
  bool raw_files = false;
};

[[nodiscard]] bool LensDatabaseAvailable();

// The distortion of the fixed-lens camera named by EXIF `make` / `model` at `focal_mm`, as it bends `camera`'s
// pixels (original image size; its focal_px normalises k1, k2). False, with why, when the database is not built in,
// does not know the camera or has no distortion for it.
[[nodiscard]] bool LookUpLensDistortion(const std::string& make, const std::string& model, double focal_mm,
                                        const PinholeCamera& camera, LensDatabaseEntry* entry, std::string* why);

// Brown (k1, k2) fitted to samples (ideal radius, distorted radius) in pixels from the principal point, normalised by
// `focal_px`. A scale at the centre (distorted / ideal radius as the radius goes to 0: a database's ideal image may
// be larger or smaller than the recorded one) is taken out first, into `centre_scale`: the mosaic's maps absorb it.
[[nodiscard]] LensDistortion FitRadialSamples(const std::vector<std::pair<double, double>>& ideal_distorted_px,
                                              double focal_px, double* centre_scale);

}  // namespace uavm
