#include "core/pipeline/frame_preparer.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/imageio/jpeg_memory.h"
#include "core/util/clock.h"

namespace uavm {

Flatness MeasureFlatness(const cv::Mat& image) {
  Flatness f;
  if (image.empty()) return f;
  cv::Scalar mean;
  cv::Scalar stddev;
  cv::meanStdDev(image, mean, stddev);
  f.uniform = std::max({stddev[0], stddev[1], stddev[2]}) < 1.0;  // under one grey level in every channel
  const double brightest = std::max({mean[0], mean[1], mean[2]});
  const double darkest = std::min({mean[0], mean[1], mean[2]});
  f.blank = f.uniform && (brightest < 16.0 || darkest > 240.0);
  return f;
}

const char* WhyNotRegistrable(const Flatness& flatness, const FrameMetadata& m) {
  if (flatness.blank) return "uniform frame (black or saturated): nothing to register";
  if (flatness.uniform && !(m.latitude_deg && m.longitude_deg))
    return "uniform frame (one colour, no position to place it by): nothing to register";
  return nullptr;
}

PreparedFrame FramePreparer::Prepare(Frame frame) const {
  PreparedFrame p = PrepareImages(std::move(frame));
  DetectFeatures(&p);
  return p;
}

void FramePreparer::DetectFeatures(PreparedFrame* p) const {
  StageTimer t;
  p->features = extractor_.Extract(p->work_gray);
  if (!p->flatness.uniform) lens_.For(p->frame, p->work_gray.size()).UndistortPoints(&p->features.points);
  p->features_ms = t.ElapsedMs();
}

PreparedFrame FramePreparer::PrepareImages(Frame frame, std::optional<Flatness> flatness) const {
  StageTimer t;
  PreparedFrame p;
  p.flatness = flatness ? *flatness : MeasureFlatness(frame.image);  // the decoded frame, before resampling smooths it
  const int long_side = std::max(frame.original_size.width, frame.original_size.height);
  const double s = std::min(1.0, work_long_side_ / static_cast<double>(long_side));
  const cv::Size work_size(std::max(1, static_cast<int>(std::lround(frame.original_size.width * s))),
                           std::max(1, static_cast<int>(std::lround(frame.original_size.height * s))));
  if (frame.image.size() == work_size)
    p.work_bgr = frame.image;
  else
    cv::resize(frame.image, p.work_bgr, work_size, 0, 0, cv::INTER_AREA);
  cv::cvtColor(p.work_bgr, p.work_gray, cv::COLOR_BGR2GRAY);
  // Features are found on the recorded pixels (no resampling) and their positions undistorted (Prepare); the live
  // view, thumbnails and tiles draw the ideal image, on which the maps act.
  if (!p.flatness.uniform) {
    const Undistorter& lens = lens_.For(frame, work_size);
    if (lens.active()) p.work_bgr = lens.UndistortImage(p.work_bgr);
  }
  if (frame.source_path.empty()) {
    // No file to copy into the session (camera, video, simulation): encode here, on the capture thread (libjpeg in
    // BGR directly: cv::imencode swapped red and blue in a scalar loop over the 12 MP first).
    std::string why;
    if (!EncodeJpegBgr(frame.image, 95, &p.encoded, &why)) {
      spdlog::warn("frame {}: not encoded for the session ({})", frame.index, why);
      p.encoded.clear();
    }
  }
  frame.image.release();  // the decoded original is not needed any more: keep queued frames small
  p.prepare_ms = t.ElapsedMs();
  p.frame = std::move(frame);
  return p;
}

cv::Mat FramePreparer::IdealGray(const PreparedFrame& p) const {
  if (p.flatness.uniform || !lens_.For(p.frame, p.work_gray.size()).active()) return p.work_gray;
  cv::Mat gray;  // the features' coordinates are the undistorted image's
  cv::cvtColor(p.work_bgr, gray, cv::COLOR_BGR2GRAY);
  return gray;
}

}  // namespace uavm
