#include "core/sfm/feature_stage.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/features/sift.h"
#include "core/util/parallel.h"

namespace uavm::sfm {

double FeatureScale(const ReconstructionOptions& options, const SessionFrame& frame) {
  if (options.feature_scale > 0.0) return options.feature_scale;
  const int long_side = std::max(frame.width, frame.height);
  return long_side > options.feature_long_side_px ? static_cast<double>(options.feature_long_side_px) / long_side : 1.0;
}

namespace {

cv::Mat ReadFrame(const std::string& path) {
  return cv::imread(path, cv::IMREAD_COLOR);
}

// 2. Features of one stored frame at feature_scale, keypoints in original-resolution pixels with their colours.
bool FrameFeaturesOf(const std::string& path, const SiftExtractor& sift, double s, FrameFeatures* out) {
  const cv::Mat img = ReadFrame(path);
  if (img.empty()) return false;
  cv::Mat gray, work;
  cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
  if (s < 1.0) {
    cv::resize(gray, work, cv::Size(), s, s, cv::INTER_AREA);
  } else {
    work = gray;
  }
  Features f = sift.Extract(work);
  out->descriptors = f.descriptors;
  for (const auto& p : f.points) {
    const double x = (p.x + 0.5) / s - 0.5, y = (p.y + 0.5) / s - 0.5;
    out->points.emplace_back(x, y);
    const int xi = std::clamp(static_cast<int>(std::lround(x)), 0, img.cols - 1);
    const int yi = std::clamp(static_cast<int>(std::lround(y)), 0, img.rows - 1);
    out->colors.push_back(img.at<cv::Vec3b>(yi, xi));
  }
  return true;
}

}  // namespace

bool ExtractFeatures(const std::string& session_dir, SelectedFrames* sel, const ReconstructionOptions& options,
                     const ProgressFn& progress, std::vector<FrameFeatures>* feats, nlohmann::json* js,
                     std::string* error) {
  const std::vector<const SessionFrame*>& frames = sel->frames;
  feats->assign(frames.size(), FrameFeatures{});
  std::vector<std::string> failures(frames.size());
  std::atomic<size_t> done{0};
  FeatureOptions fo;
  fo.max_features = options.max_features;
  // A higher start threshold than the onboard one: offline, repeatable (contrasted) keypoints matter more than many.
  fo.contrast_threshold = options.contrast_threshold;
  fo.target_min_features = options.max_features / 4;
  fo.max_scale_space_mib = 1200;  // bands the 4000 px frames: two threads stay within a few GiB
  // OpenCV's SIFT offline, for now: the flat-field reconstruction test sits at 0.99 m of its 1 m limit with its
  // keypoints and at 1.7-2.2 m with the onboard one's (the same keypoints to 0.001 px, the same 0.05 px residual after
  // adjustment: the dome of a 5-frame nadir block with a guessed focal length, not the keypoints).
  fo.opencv_sift = true;
  const SiftExtractor sift(fo);
  // Each worker runs a single-threaded SIFT; OpenCV's own pool would oversubscribe the cores.
  const int cv_threads = cv::getNumThreads();
  cv::setNumThreads(options.threads > 1 ? 1 : cv_threads);
  ParallelFor(frames.size(), options.threads, [&](size_t i) {
    const double scale = FeatureScale(options, *frames[i]);
    if (!FrameFeaturesOf(session_dir + "/" + frames[i]->stored_file, sift, scale, &(*feats)[i])) {
      failures[i] = "cannot read " + frames[i]->stored_file;
      return;
    }
    if (progress) progress("features", ++done, frames.size());
  });
  cv::setNumThreads(cv_threads);
  size_t kept = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (!failures[i].empty()) {
      std::fprintf(stderr, "uavmosaic-ground: warning: frame %d (%s) left out: %s\n", frames[i]->index,
                   frames[i]->filename.c_str(), failures[i].c_str());
      sel->left_out.emplace_back(frames[i], failures[i]);
      continue;
    }
    if (kept != i) {  // (a vector moved onto itself is left empty)
      sel->frames[kept] = frames[i];
      (*feats)[kept] = std::move((*feats)[i]);
    }
    ++kept;
  }
  sel->frames.resize(kept);
  feats->resize(kept);
  sel->slot_of.clear();
  for (size_t i = 0; i < kept; ++i) sel->slot_of[sel->frames[i]->index] = i;
  (*js)["frames_not_used"] = LeftOutJson(*sel);
  if (kept < 2) {
    *error = "fewer than two readable frames (" + std::to_string(sel->left_out.size()) + " left out)";
    return false;
  }
  size_t total_kp = 0;
  for (const auto& f : *feats) total_kp += f.points.size();
  (*js)["keypoints_per_frame_mean"] = static_cast<double>(total_kp) / static_cast<double>(frames.size());
  (*js)["feature_scale"] = FeatureScale(options, *frames[0]);
  return true;
}

}  // namespace uavm::sfm
