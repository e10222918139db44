#pragma once
#include <string>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm::eval {

// gt.csv, written by the simulator next to a flight: per frame the exact projective canvas_from_frame (row-major,
// c22 = 1) and the affine closest to it over the frame (least squares on a grid), original-resolution frame pixels.
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

// The affine minimising the squared distance to `projective` over a grid x grid lattice of pixel centres spanning a
// width x height frame.
[[nodiscard]] Mat3 ClosestAffine(const Mat3& projective, int width, int height, int grid = 17);

}  // namespace uavm::eval
