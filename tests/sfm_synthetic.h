// Synthetic aerial scenes for the sfm tests: nadir-ish cameras over gently rolling ground, exact observations.
#pragma once
#include <Eigen/Geometry>

#include "core/sfm/reconstruction.h"
#include "core/util/portable_random.h"

namespace uavm::sfm::testing {

inline Camera TestCamera() {
  Camera c;
  c.width = 1600;
  c.height = 1200;
  c.fx = c.fy = 1400.0;
  c.cx = 801.3;
  c.cy = 597.8;
  c.k1 = -0.08;
  c.k2 = 0.03;
  c.p1 = 4e-4;
  c.p2 = -3e-4;
  return c;
}

// Camera at c looking down (z down in camera = -world z) with yaw and small tilts (radians).
inline Pose NadirPose(const Eigen::Vector3d& c, double yaw, double tilt_x = 0.0, double tilt_y = 0.0) {
  Eigen::Matrix3d down;
  down << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // camera x = east, y = south, z = down
  const Eigen::Matrix3d Rw =
      (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
       Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()))
          .toRotationMatrix();
  Pose p;
  p.R = down * Rw.transpose();
  p.c = c;
  return p;
}

inline double Terrain(double x, double y) {
  return 6.0 * std::sin(x / 15.0) * std::cos(y / 11.0) + 0.02 * x;
}

// The same camera set to 0.9x its image size for some shots (its own lens terms, as a second body would have).
inline Camera SecondTestCamera() {
  Camera c = TestCamera();
  c.width = 1440;
  c.height = 1080;
  c.fx = c.fy = 1260.0;
  c.cx = 721.0;
  c.cy = 538.2;
  c.k1 = -0.05;
  c.k2 = 0.01;
  c.p1 = c.p2 = 0.0;
  return c;
}

// 3 x 4 grid of cameras at 60 m, points on the terrain, each point observed by every camera that sees it. With
// `two_cameras`, every other image is taken with SecondTestCamera().
inline Reconstruction MakeScene(double noise_px, unsigned seed, int n_points = 1500, bool two_cameras = false) {
  // The same scene on every platform (core/util/portable_random.h), each draw in its own statement (the order in
  // which a call's arguments are evaluated is unspecified).
  PortableRandom rng(seed);
  Reconstruction rec;
  rec.cameras = {TestCamera()};
  if (two_cameras) rec.cameras.push_back(SecondTestCamera());
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 4; ++k) {
      Image im;
      im.frame_index = r * 4 + k;
      im.name = "img" + std::to_string(im.frame_index) + ".jpg";
      im.camera = two_cameras ? im.frame_index % 2 : 0;
      const double tilt_x = rng.Uniform(-0.08, 0.08);
      const double tilt_y = rng.Uniform(-0.08, 0.08);
      im.pose = NadirPose(Eigen::Vector3d(k * 12.0, r * 14.0, 60.0 + 0.5 * k), 0.1 * r, tilt_x, tilt_y);
      rec.images.push_back(im);
    }
  }
  for (int i = 0; i < n_points; ++i) {
    const double x = rng.Uniform(-40.0, 70.0);
    const double y = rng.Uniform(-30.0, 50.0);
    Point3D p;
    p.X = Eigen::Vector3d(x, y, Terrain(x, y));
    for (size_t c = 0; c < rec.images.size(); ++c) {
      // Noise is drawn for every camera, seen or not: a point at the image border that one platform's rounding puts
      // just inside and another's just outside then changes that one observation, not every draw after it.
      const double nx = rng.Normal(noise_px);
      const double ny = rng.Normal(noise_px);
      const Eigen::Vector2d n(nx, ny);
      const Camera& cam = rec.CameraOf(rec.images[c]);
      const auto m = Project(cam, rec.images[c].pose, p.X);
      if (!m || m->x() < 0 || m->y() < 0 || m->x() > cam.width - 1 || m->y() > cam.height - 1) continue;
      auto& kps = rec.images[c].keypoints;
      kps.push_back(*m + n);
      p.track.push_back({static_cast<int>(c), static_cast<int>(kps.size() - 1)});
    }
    if (p.track.size() >= 2) rec.points.push_back(p);
  }
  return rec;
}

}  // namespace uavm::sfm::testing
