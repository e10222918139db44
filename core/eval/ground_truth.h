#pragma once
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "core/geometry/camera_model.h"
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

// The camera's truth, in files of their own beside gt.csv (whose format and readers stay as they were):
//   gt_camera.yaml   the lens: a `camera` block (width, height, focal_px, cx, cy, k1, k2, p1, p2: PinholeCamera,
//                    core/geometry/camera_model.h) and a `vignetting` block (half_diagonal_px, and per channel b, g, r
//                    the pair [a1, a2] of V(r) = 1 + a1 r^2 + a2 r^4, r = distance to (cx, cy) / half_diagonal_px).
//                    gt.csv's canvas_from_frame maps *undistorted* frame pixels (PinholeCamera::UndistortPixel).
//   gt_exposure.csv  per frame: index, filename, gain, offset, wb_b, wb_g, wb_r; a recorded pixel of channel c is
//                    gain * wb_c * V_c(r) * canvas_c + offset (before noise, clipping and JPEG).
inline constexpr const char* kGroundTruthCameraFile = "gt_camera.yaml";
inline constexpr const char* kGroundTruthExposureFile = "gt_exposure.csv";
inline constexpr const char* kGroundTruthExposureHeader = "index,filename,gain,offset,wb_b,wb_g,wb_r";

struct GtCamera {
  PinholeCamera camera;
  double half_diagonal_px = 0.0;
  std::array<RadialFalloff, 3> vignetting;  // B, G, R
};

struct GtExposure {
  int index = -1;
  std::string filename;
  double gain = 1.0;
  double offset = 0.0;
  std::array<double, 3> white_balance{1.0, 1.0, 1.0};  // B, G, R
};

[[nodiscard]] std::string FormatGroundTruthCamera(const GtCamera& camera);
[[nodiscard]] bool ParseGroundTruthCamera(const std::string& text, GtCamera* camera, std::string* error);
// The `camera` block of a YAML text (gt_camera.yaml's layout; other blocks are ignored): a session's lens model too.
[[nodiscard]] bool ParseCameraBlock(const std::string& text, PinholeCamera* camera, std::string* error);
[[nodiscard]] std::string FormatGroundTruthExposure(const std::vector<GtExposure>& rows);
[[nodiscard]] bool ParseGroundTruthExposure(const std::string& text, std::vector<GtExposure>* rows, std::string* error);
// gt_camera.yaml beside `gt_csv_path`: nullopt when there is none (a flight simulated before the lens keys: an
// ideal camera); false with a reason when it exists but cannot be read.
[[nodiscard]] bool LoadGroundTruthCamera(const std::string& gt_csv_path, std::optional<GtCamera>* camera,
                                         std::string* error);

}  // namespace uavm::eval
