#pragma once
#include <string>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm::eval {

// gt.csv, written by the simulator next to a flight: per frame the exact projective canvas_from_frame (row-major,
// c22 = 1) and the affine closest to it over the frame (ClosestAffine, core/geometry/transform.h), original-resolution
// frame pixels.
inline constexpr const char* kGroundTruthHeader =
    "index,filename,c00,c01,c02,c10,c11,c12,c20,c21,c22,a00,a01,a02,a10,a11,a12";

struct GtRow {
  int index = -1;
  std::string filename;
  Mat3 canvas_from_frame = Mat3::Identity();
  Mat3 affine = Mat3::Identity();  // last row (0, 0, 1)
};

[[nodiscard]] std::string FormatGroundTruthCsv(const std::vector<GtRow>& rows);
[[nodiscard]] bool ParseGroundTruthCsv(const std::string& text, std::vector<GtRow>* rows, std::string* error);

}  // namespace uavm::eval
