#include "core/sfm/dense.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <unordered_map>

#include "core/stereo/pair_depth.h"

namespace uavm::sfm {

nlohmann::json DenseReport::ToJson() const {
  nlohmann::json j = nlohmann::json::object();
  nlohmann::json jp = nlohmann::json::array();
  for (size_t k = 0; k < pairs.size(); ++k) {
    jp.push_back({{"image1", pairs[k].image1},
                  {"image2", pairs[k].image2},
                  {"baseline_ratio", pairs[k].baseline_ratio},
                  {"overlap", pairs[k].overlap},
                  {"points", k < points_per_pair.size() ? points_per_pair[k] : 0},
                  {"seconds", k < seconds_per_pair.size() ? seconds_per_pair[k] : 0.0}});
  }
  j["pairs"] = jp;
  j["raw_points"] = raw_points;
  j["failures"] = failures;
  return j;
}

nlohmann::json FusionReport::ToJson() const {
  return {{"input_points", input},
          {"cells", cells},
          {"cells_consistent", cells_consistent},
          {"kept_points", kept_points},
          {"output_points", output_points}};
}

std::vector<StereoPairChoice> SelectStereoPairs(const Reconstruction& rec, const DenseOptions& options) {
  const size_t n = rec.images.size();
  std::vector<std::vector<size_t>> seen(n);  // point ids per image
  for (size_t p = 0; p < rec.points.size(); ++p) {
    for (const auto& o : rec.points[p].track) seen[static_cast<size_t>(o.image)].push_back(p);
  }
  // Per image its candidates (score, choice); the best pairs_per_image are kept.
  std::vector<std::vector<std::pair<double, StereoPairChoice>>> cands(n);
  for (size_t i = 0; i < n; ++i) {
    if (seen[i].size() < 20) continue;
    std::vector<double> depth;
    for (size_t p : seen[i]) depth.push_back(rec.images[i].pose.ToCamera(rec.points[p].X).z());
    std::sort(depth.begin(), depth.end());
    const double med = depth[depth.size() / 2];
    std::vector<int> count(n, 0);
    for (size_t p : seen[i]) {
      for (const auto& o : rec.points[p].track) ++count[static_cast<size_t>(o.image)];
    }
    for (size_t j = 0; j < n; ++j) {
      if (j == i) continue;
      const double overlap = static_cast<double>(count[j]) / static_cast<double>(seen[i].size());
      const double ratio = (rec.images[i].pose.c - rec.images[j].pose.c).norm() / med;
      if (overlap < options.min_overlap || ratio < options.min_baseline_ratio || ratio > options.max_baseline_ratio)
        continue;
      StereoPairChoice c;
      c.image1 = static_cast<int>(i);
      c.image2 = static_cast<int>(j);
      c.baseline_ratio = ratio;
      c.overlap = overlap;
      // Depth range with margin: the sparse points' 1st..99th percentile.
      c.min_depth = 0.7 * depth[depth.size() / 100];
      c.max_depth = 1.4 * depth[depth.size() - 1 - depth.size() / 100];
      cands[i].emplace_back(std::abs(ratio - options.target_baseline_ratio) - 0.1 * overlap, c);
    }
    std::sort(cands[i].begin(), cands[i].end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    if (static_cast<int>(cands[i].size()) > options.pairs_per_image) {
      cands[i].resize(static_cast<size_t>(options.pairs_per_image));
    }
  }
  std::vector<std::pair<double, StereoPairChoice>> chosen;
  std::set<std::pair<int, int>> have;
  for (size_t i = 0; i < n; ++i) {
    for (const auto& [score, c] : cands[i]) {
      const auto key = std::minmax(c.image1, c.image2);
      if (!have.insert(key).second) continue;
      chosen.emplace_back(score, c);
    }
  }
  std::sort(chosen.begin(), chosen.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<StereoPairChoice> out;
  for (const auto& c : chosen) {
    if (static_cast<int>(out.size()) >= options.max_pairs) break;
    out.push_back(c.second);
  }
  return out;
}

namespace {
stereo::StereoCamera ToStereo(const Camera& cam, const Pose& pose) {
  stereo::StereoCamera s;
  s.K = cam.K();
  s.dist = cam.Dist();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) s.R(r, c) = pose.R(r, c);
  s.c = cv::Vec3d(pose.c.x(), pose.c.y(), pose.c.z());
  s.size = cv::Size(cam.width, cam.height);
  return s;
}
}  // namespace

bool DenseFromReconstruction(const Reconstruction& rec, const std::vector<std::string>& image_paths,
                             const DenseOptions& options, const DenseProgressFn& progress,
                             std::vector<CloudPoint>* points, DenseReport* report, std::string* error) {
  report->pairs = SelectStereoPairs(rec, options);
  points->clear();
  for (size_t k = 0; k < report->pairs.size(); ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    const auto& pc = report->pairs[k];
    const cv::Mat img1 = cv::imread(image_paths[static_cast<size_t>(pc.image1)], cv::IMREAD_COLOR);
    const cv::Mat img2 = cv::imread(image_paths[static_cast<size_t>(pc.image2)], cv::IMREAD_COLOR);
    if (img1.empty() || img2.empty()) {
      *error = "cannot read the images of a stereo pair";
      return false;
    }
    stereo::PairDepthOptions po;
    po.min_depth = pc.min_depth;
    po.max_depth = pc.max_depth;
    po.image_scale = options.image_scale;
    po.sample_step = options.sample_step;
    if (options.daisy_cost) po.sgm.cost = stereo::SgmOptions::Cost::kDaisy;
    std::vector<stereo::ColoredPoint> pts;
    std::string why;
    const bool ok = stereo::DensePointsFromPair(
        img1, ToStereo(rec.CameraOf(pc.image1), rec.images[static_cast<size_t>(pc.image1)].pose), img2,
        ToStereo(rec.CameraOf(pc.image2), rec.images[static_cast<size_t>(pc.image2)].pose), po, &pts, &why);
    if (!ok) report->failures.push_back(std::to_string(pc.image1) + "-" + std::to_string(pc.image2) + ": " + why);
    for (const auto& p : pts) {
      if (!std::isfinite(p.xyz[0]) || !std::isfinite(p.xyz[1]) || !std::isfinite(p.xyz[2])) continue;
      points->push_back({p.xyz, p.bgr});
      report->point_pair.push_back(static_cast<int>(k));
    }
    report->points_per_pair.push_back(ok ? pts.size() : 0);
    report->seconds_per_pair.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    if (progress) progress("dense", k + 1, report->pairs.size());
  }
  report->raw_points = points->size();
  return true;
}

std::vector<CloudPoint> FuseClouds(const std::vector<CloudPoint>& points, const std::vector<int>& pair_of, double cell,
                                   double tolerance, int min_pairs, FusionReport* report) {
  FusionReport rep;
  rep.input = points.size();
  auto key2 = [&](const CloudPoint& p) {
    const auto cx = static_cast<int64_t>(std::floor(p.xyz[0] / cell));
    const auto cy = static_cast<int64_t>(std::floor(p.xyz[1] / cell));
    return (cx << 32) ^ (cy & 0xffffffff);
  };
  std::unordered_map<int64_t, std::vector<uint32_t>> cells;
  for (uint32_t i = 0; i < points.size(); ++i) cells[key2(points[i])].push_back(i);
  rep.cells = cells.size();
  struct Acc {
    double x = 0, y = 0, z = 0, b = 0, g = 0, r = 0;
    int n = 0;
  };
  std::unordered_map<int64_t, Acc> voxels;
  std::vector<int64_t> order;
  for (auto& [key, idx] : cells) {
    std::vector<float> z;
    for (auto i : idx) z.push_back(points[i].xyz[2]);
    std::nth_element(z.begin(), z.begin() + static_cast<long>(z.size() / 2), z.end());
    const double med = z[z.size() / 2];
    std::set<int> pairs;
    for (auto i : idx) {
      if (std::abs(points[i].xyz[2] - med) <= tolerance) pairs.insert(pair_of[i]);
    }
    if (static_cast<int>(pairs.size()) < min_pairs) continue;
    ++rep.cells_consistent;
    for (auto i : idx) {
      const auto& p = points[i];
      if (std::abs(p.xyz[2] - med) > tolerance) continue;
      ++rep.kept_points;
      const auto cz = static_cast<int64_t>(std::floor(p.xyz[2] / cell));
      const int64_t vkey = key * 1000003 + cz;  // voxel within the cell's column
      auto [it, inserted] = voxels.try_emplace(vkey);
      if (inserted) order.push_back(vkey);
      Acc& a = it->second;
      a.x += p.xyz[0];
      a.y += p.xyz[1];
      a.z += p.xyz[2];
      a.b += p.bgr[0];
      a.g += p.bgr[1];
      a.r += p.bgr[2];
      ++a.n;
    }
  }
  std::vector<CloudPoint> out;
  out.reserve(voxels.size());
  for (auto k : order) {
    const Acc& a = voxels[k];
    const double n = a.n;
    out.push_back({cv::Vec3f(static_cast<float>(a.x / n), static_cast<float>(a.y / n), static_cast<float>(a.z / n)),
                   cv::Vec3b(cv::saturate_cast<uchar>(a.b / n), cv::saturate_cast<uchar>(a.g / n),
                             cv::saturate_cast<uchar>(a.r / n))});
  }
  rep.output_points = out.size();
  if (report) *report = rep;
  return out;
}

}  // namespace uavm::sfm
