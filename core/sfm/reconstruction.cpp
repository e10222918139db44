#include "core/sfm/reconstruction.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace uavm::sfm {

size_t Reconstruction::NumObservations() const {
  size_t n = 0;
  for (const auto& p : points) n += p.track.size();
  return n;
}

double Reconstruction::ReprojectionRms() const {
  double sum = 0.0;
  size_t n = 0;
  for (const auto& p : points) {
    for (const auto& o : p.track) {
      const auto& im = images[static_cast<size_t>(o.image)];
      const auto proj = Project(camera, im.pose, p.X);
      if (!proj) continue;
      sum += (*proj - im.keypoints[static_cast<size_t>(o.feature)]).squaredNorm();
      ++n;
    }
  }
  return n ? std::sqrt(sum / static_cast<double>(n)) : 0.0;
}

double Reconstruction::MedianGsd() const {
  std::vector<double> depths;
  for (const auto& p : points) {
    for (const auto& o : p.track) depths.push_back(images[static_cast<size_t>(o.image)].pose.ToCamera(p.X).z());
  }
  if (depths.empty() || camera.fx <= 0.0) return 0.0;
  std::nth_element(depths.begin(), depths.begin() + static_cast<long>(depths.size() / 2), depths.end());
  return depths[depths.size() / 2] / camera.fx;
}

void Reconstruction::Transform(const Similarity3& s) {
  for (auto& im : images) {
    im.pose.c = s.Apply(im.pose.c);
    im.pose.R = im.pose.R * s.rotation.transpose();
  }
  for (auto& p : points) p.X = s.Apply(p.X);
}

}  // namespace uavm::sfm
