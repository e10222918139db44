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
      const auto proj = Project(CameraOf(im), im.pose, p.X);
      if (!proj) continue;
      sum += (*proj - im.keypoints[static_cast<size_t>(o.feature)]).squaredNorm();
      ++n;
    }
  }
  return n ? std::sqrt(sum / static_cast<double>(n)) : 0.0;
}

std::vector<Reconstruction::ImageResidual> Reconstruction::ResidualsPerImage() const {
  std::vector<ImageResidual> out(images.size());
  std::vector<double> sum(images.size(), 0.0);
  for (const auto& p : points) {
    for (const auto& o : p.track) {
      const auto i = static_cast<size_t>(o.image);
      const auto proj = Project(CameraOf(images[i]), images[i].pose, p.X);
      if (!proj) continue;
      sum[i] += (*proj - images[i].keypoints[static_cast<size_t>(o.feature)]).squaredNorm();
      ++out[i].observations;
    }
  }
  for (size_t i = 0; i < out.size(); ++i)
    out[i].rms_px = out[i].observations > 0 ? std::sqrt(sum[i] / static_cast<double>(out[i].observations)) : 0.0;
  return out;
}

double Reconstruction::MedianGsd() const {
  std::vector<double> gsd;  // per observation: its depth over its camera's focal length
  for (const auto& p : points) {
    for (const auto& o : p.track) {
      const Image& im = images[static_cast<size_t>(o.image)];
      if (CameraOf(im).fx > 0.0) gsd.push_back(im.pose.ToCamera(p.X).z() / CameraOf(im).fx);
    }
  }
  if (gsd.empty()) return 0.0;
  std::nth_element(gsd.begin(), gsd.begin() + static_cast<long>(gsd.size() / 2), gsd.end());
  return gsd[gsd.size() / 2];
}

void Reconstruction::Transform(const Similarity3& s) {
  for (auto& im : images) {
    im.pose.c = s.Apply(im.pose.c);
    im.pose.R = im.pose.R * s.rotation.transpose();
  }
  for (auto& p : points) p.X = s.Apply(p.X);
}

}  // namespace uavm::sfm
