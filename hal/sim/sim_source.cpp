#include "hal/sim/sim_source.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "core/geometry/transform.h"
#include "core/util/clock.h"

namespace uavm::hal {

SimSource::SimSource(SimOptions options) : options_(std::move(options)) {}

std::string SimSource::Describe() const {
  return "sim:" + (options_.plan_path.empty() ? std::string("<inline plan>") : options_.plan_path);
}

size_t SimSource::NumFrames() const {
  if (options_.max_frames > 0) return std::min(poses_.size(), static_cast<size_t>(options_.max_frames));
  return poses_.size();
}

std::string SimSource::FrameName(uint64_t index) const {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "frame_%06llu.%s", static_cast<unsigned long long>(index),
                plan_.jpeg_quality > 0 ? "jpg" : "png");
  return buf;
}

Status SimSource::Open(std::string* error) {
  std::string base_dir;
  if (!options_.plan_path.empty()) {
    std::ifstream in(options_.plan_path);
    if (!in) {
      *error = "cannot read sim plan " + options_.plan_path;
      return Status::kError;
    }
    std::stringstream ss;
    ss << in.rdbuf();
    plan_text_ = ss.str();
    base_dir = std::filesystem::path(options_.plan_path).parent_path().string();
  } else {
    plan_text_ = options_.plan_yaml;
  }
  if (!ParseSimPlan(plan_text_, base_dir, &plan_, error)) {
    if (!options_.plan_path.empty()) *error = options_.plan_path + ": " + *error;
    return Status::kError;
  }
  if (!options_.canvas_path.empty()) plan_.canvas = options_.canvas_path;
  if (plan_.canvas.empty()) {
    *error = "sim: no canvas image (plan key 'canvas' or the canvas option)";
    return Status::kError;
  }
  try {
    canvas_ = cv::imread(plan_.canvas, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
  } catch (const cv::Exception&) {
    canvas_.release();
  }
  if (canvas_.empty()) {
    *error = "sim: cannot read canvas image " + plan_.canvas;
    return Status::kError;
  }
  PaintWater();
  std::string note;
  if (!BuildFlight(plan_, canvas_.size(), &poses_, &note, error)) return Status::kError;
  if (!note.empty()) spdlog::warn("{}", note);
  spdlog::info("sim: {} frames of {}x{} over a {}x{} canvas", NumFrames(), plan_.frame_width, plan_.frame_height,
               canvas_.cols, canvas_.rows);
  next_ = 0;
  return Status::kOk;
}

// Calm water: one colour with a gentle gradient (under one grey level across a frame), so a frame wholly over it has
// no features and looks "uniform" to the input checks, as real calm water does.
void SimSource::PaintWater() {
  if (!(plan_.water_to > plan_.water_from)) return;
  const int x0 = static_cast<int>(std::lround(plan_.water_from * canvas_.cols));
  const int x1 = static_cast<int>(std::lround(plan_.water_to * canvas_.cols));
  if (x1 <= x0) return;
  cv::Mat band = canvas_.colRange(x0, x1);
  for (int y = 0; y < band.rows; ++y) {
    const double shade = 4.0 * y / std::max(1, band.rows - 1);  // 4 grey levels over the whole canvas height
    band.row(y).setTo(cv::Scalar(118 + shade, 96 + shade, 52 + shade));
  }
}

const cv::Mat& SimSource::CanvasLevel(int level) {
  if (level <= 0) return canvas_;
  auto it = levels_.find(level);
  if (it != levels_.end()) return it->second;
  const double f = std::pow(2.0, -level / 4.0);
  cv::Mat reduced;
  cv::resize(canvas_, reduced,
             cv::Size(std::max(1, static_cast<int>(std::lround(canvas_.cols * f))),
                      std::max(1, static_cast<int>(std::lround(canvas_.rows * f)))),
             0, 0, cv::INTER_AREA);
  return levels_.emplace(level, std::move(reduced)).first->second;
}

void SimSource::SimulateGps(size_t i, cv::Size size, SimTruth* truth) const {
  const Vec2 ground = Apply(truth->canvas_from_frame, Vec2((size.width - 1.0) / 2, (size.height - 1.0) / 2));
  truth->true_position = CanvasToLatLon(plan_, canvas_.size(), ground);
  // Per-frame generator (frame i's fix does not depend on the frames before), plus a slowly turning bias.
  cv::RNG rng(plan_.seed * 7919ULL + i + 1);
  const double turn = 2.0 * M_PI * static_cast<double>(i) / 200.0;
  const double east_px = (plan_.gps_bias_m * std::cos(turn) + rng.gaussian(plan_.gps_noise_m)) / plan_.metres_per_px;
  const double south_px = -(plan_.gps_bias_m * std::sin(turn) + rng.gaussian(plan_.gps_noise_m)) / plan_.metres_per_px;
  truth->gps_position = CanvasToLatLon(plan_, canvas_.size(), ground + Vec2(east_px, south_px));
  truth->gps_altitude_m = plan_.flight_altitude_m * truth->pose.altitude;
  // Compass heading of the direction of flight (frame +x): canvas +x is east, +y south, so yaw 0 is 90 deg.
  const double heading = 90.0 + truth->pose.yaw_deg + rng.gaussian(plan_.heading_noise_deg);
  truth->gps_heading_deg = std::fmod(std::fmod(heading, 360.0) + 360.0, 360.0);
}

bool SimSource::Render(size_t i, cv::Mat* image, SimTruth* truth, std::vector<uchar>* encoded, std::string* error) {
  if (i >= poses_.size()) {
    *error = "sim: no frame " + std::to_string(i);
    return false;
  }
  const SimPose& pose = poses_[i];
  const cv::Size size(plan_.frame_width, plan_.frame_height);
  truth->index = i;
  truth->pose = pose;
  truth->canvas_from_frame = CanvasFromFrame(plan_, pose);
  truth->affine = ClosestAffine(truth->canvas_from_frame, size.width, size.height);
  if (plan_.gps != 0) SimulateGps(i, size, truth);

  // Bilinear sampling aliases when a frame pixel covers several canvas pixels: sample a pre-reduced canvas
  // (quarter-octave levels) so the remaining reduction is below 2^(1/4).
  const Vec2 centre((size.width - 1.0) / 2, (size.height - 1.0) / 2);
  const double s = LocalScale(truth->canvas_from_frame, centre);
  const int level = s > 1.0 ? static_cast<int>(std::floor(std::log2(s) * 4.0)) : 0;
  const cv::Mat& src = CanvasLevel(level);
  const Mat3 src_from_frame =
      ResizeMap(static_cast<double>(src.cols) / canvas_.cols, static_cast<double>(src.rows) / canvas_.rows) *
      truth->canvas_from_frame;
  cv::Mat frame;
  // WARP_INVERSE_MAP: the matrix maps destination (frame) pixels to source pixels, exactly the truth's direction.
  cv::warpPerspective(src, frame, ToCv(src_from_frame), size, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                      cv::BORDER_REFLECT);

  if (plan_.blur_px > 0) {
    // Motion blur along frame x (the flight direction), a centred box of the given length with fractional ends,
    // so the blur moves no content.
    const double len = plan_.blur_px;
    const int half = static_cast<int>(std::ceil(len / 2.0));
    cv::Mat k(1, 2 * half + 1, CV_32F);
    for (int x = -half; x <= half; ++x)
      k.at<float>(0, x + half) = static_cast<float>(std::clamp(len / 2.0 - std::abs(x) + 0.5, 0.0, 1.0));
    k /= cv::sum(k)[0];
    cv::filter2D(frame, frame, -1, k, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  }
  if (pose.gain != 1.0 || pose.offset != 0.0 || plan_.noise_sigma > 0) {
    cv::Mat f;
    frame.convertTo(f, CV_32F, pose.gain, pose.offset);
    if (plan_.noise_sigma > 0) {
      // Per-frame generator: frame i's noise does not depend on which frames were rendered before.
      cv::RNG rng(plan_.seed * 1000003ULL + i + 1);
      cv::Mat noise(f.size(), f.type());
      rng.fill(noise, cv::RNG::NORMAL, 0.0, plan_.noise_sigma);
      f += noise;
    }
    f.convertTo(frame, CV_8U);
  }
  encoded->clear();
  if (plan_.jpeg_quality > 0) {
    if (!cv::imencode(".jpg", frame, *encoded, {cv::IMWRITE_JPEG_QUALITY, plan_.jpeg_quality})) {
      *error = "sim: JPEG encoding failed";
      return false;
    }
    frame = cv::imdecode(*encoded, cv::IMREAD_COLOR);
    if (frame.empty()) {
      *error = "sim: JPEG decoding failed";
      return false;
    }
  }
  *image = std::move(frame);
  return true;
}

Status SimSource::Next(Frame* frame, std::string* error) {
  if (canvas_.empty()) {
    *error = "sim source is not open";
    return Status::kError;
  }
  if (next_ >= NumFrames()) return Status::kEndOfStream;
  cv::Mat image;
  try {
    if (!Render(next_, &image, &truth_, &encoded_, error)) return Status::kError;
  } catch (const std::exception& e) {  // OpenCV errors (e.g. out of memory) stay inside the source
    *error = std::string("sim: rendering failed: ") + e.what();
    return Status::kError;
  }
  *frame = Frame{};
  frame->index = next_;
  frame->timestamp_ns = MonotonicNs();
  frame->source_name = FrameName(next_);
  frame->original_size = image.size();
  frame->image = std::move(image);
  frame->decode_scale = 1.0;
  if (plan_.gps != 0) {  // as a camera's EXIF GPS would carry it
    frame->metadata.latitude_deg = truth_.gps_position.lat_deg;
    frame->metadata.longitude_deg = truth_.gps_position.lon_deg;
    frame->metadata.relative_altitude_m = truth_.gps_altitude_m;
    frame->metadata.flight_yaw_deg = truth_.gps_heading_deg;
  }
  ++next_;
  return Status::kOk;
}

void SimSource::Close() {
  canvas_.release();
  levels_.clear();
}

}  // namespace uavm::hal
