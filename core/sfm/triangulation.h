#pragma once
#include <Eigen/Core>
#include <optional>
#include <vector>

#include "core/sfm/camera.h"

namespace uavm::sfm {

// DLT triangulation over all n observations: the 2n x 4 system [x P3 - P1; y P3 - P2] on normalised undistorted
// coordinates (rows scaled to unit norm), solved by JacobiSVD. nullopt with fewer than two views or a point at
// infinity.
[[nodiscard]] std::optional<Eigen::Vector3d> TriangulateDlt(const std::vector<Pose>& poses,
                                                            const std::vector<Eigen::Vector2d>& normalized);

struct TriangulationOptions {
  double max_reprojection_px = 4.0;  // every observation must reproject within this
  double min_angle_deg = 1.0;        // largest angle between two viewing rays at the point
  [[nodiscard]] bool Check() const { return max_reprojection_px > 0.0 && min_angle_deg >= 0.0; }
};

// Largest angle (deg) between viewing rays from the camera centres to X.
[[nodiscard]] double MaxTriangulationAngleDeg(const std::vector<Pose>& poses, const Eigen::Vector3d& X);

}  // namespace uavm::sfm
