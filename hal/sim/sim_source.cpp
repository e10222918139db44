#include "hal/sim/sim_source.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <thread>

#include "core/geometry/transform.h"
#include "core/util/clock.h"
#include "hal/sim/sim_telemetry.h"

namespace uavm::hal {

namespace {

double Wrap360(double deg) {
  return std::fmod(std::fmod(deg, 360.0) + 360.0, 360.0);
}
double Lerp(double a, double b, double w) {
  return a + (b - a) * w;
}

}  // namespace

SimSource::SimSource(SimOptions options) : options_(std::move(options)) {}
SimSource::~SimSource() = default;

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
  PaintSimWater(plan_, &canvas_);
  PrepareLens();
  std::string note;
  if (!BuildFlight(plan_, canvas_.size(), &poses_, &note, error)) return Status::kError;
  if (!note.empty()) spdlog::warn("{}", note);
  spdlog::info("sim: {} frames of {}x{} over a {}x{} canvas", NumFrames(), plan_.frame_width, plan_.frame_height,
               canvas_.cols, canvas_.rows);
  next_ = 0;
  link_.reset();
  signing_key_.reset();
  if (!plan_.mavlink_signing_key_file.empty()) {
    mavlink::SigningKey key{};
    if (!mavlink::ReadSigningKey(plan_.mavlink_signing_key_file, &key, error)) return Status::kError;
    signing_key_ = key;
  }
  if (options_.live_link && !plan_.mavlink_udp.empty()) {
    link_ = std::make_unique<SimUdpLink>(this);
    if (!link_->Open(plan_.mavlink_udp, error)) return Status::kError;
    spdlog::info("sim: MAVLink telemetry to udp {}, frames {} s apart in real time", plan_.mavlink_udp,
                 plan_.frame_interval_s);
  }
  return Status::kOk;
}

// Calm water: one colour with a gentle gradient (under one grey level across a frame), so a frame wholly over it has
// no features and looks "uniform" to the input checks, as real calm water does.
void PaintSimWater(const SimPlan& plan, cv::Mat* canvas) {
  if (!(plan.water_to > plan.water_from)) return;
  const int x0 = static_cast<int>(std::lround(plan.water_from * canvas->cols));
  const int x1 = static_cast<int>(std::lround(plan.water_to * canvas->cols));
  if (x1 <= x0) return;
  cv::Mat band = canvas->colRange(x0, x1);
  for (int y = 0; y < band.rows; ++y) {
    const double shade = 4.0 * y / std::max(1, band.rows - 1);  // 4 grey levels over the whole canvas height
    band.row(y).setTo(cv::Scalar(118 + shade, 96 + shade, 52 + shade));
  }
}

// The lens, once per flight: every frame has the same camera, so the undistorted position of each recorded pixel and
// the vignetting of each pixel are the same for all frames.
void SimSource::PrepareLens() {
  const PinholeCamera camera = plan_.Camera();
  const cv::Size size(plan_.frame_width, plan_.frame_height);
  ideal_from_frame_.release();
  falloff_.release();
  if (!camera.distortion.IsZero()) {
    ideal_from_frame_.create(size, CV_32FC2);
    for (int y = 0; y < size.height; ++y)
      for (int x = 0; x < size.width; ++x) {
        const Vec2 u = camera.UndistortPixel(Vec2(x, y));
        ideal_from_frame_.at<cv::Vec2f>(y, x) = cv::Vec2f(static_cast<float>(u.x()), static_cast<float>(u.y()));
      }
  }
  if (plan_.vignetting < 1.0) {
    falloff_.create(size, CV_32FC3);
    const double half_diagonal = 0.5 * std::hypot(size.width, size.height);
    const std::array<RadialFalloff, 3> v{plan_.Vignetting(0), plan_.Vignetting(1), plan_.Vignetting(2)};
    const double shading_x = camera.cx + plan_.shading_offset_x * half_diagonal;  // the falloff's centre
    const double shading_y = camera.cy + plan_.shading_offset_y * half_diagonal;
    for (int y = 0; y < size.height; ++y)
      for (int x = 0; x < size.width; ++x) {
        const double r = std::hypot(x - shading_x, y - shading_y) / half_diagonal;
        falloff_.at<cv::Vec3f>(y, x) =
            cv::Vec3f(static_cast<float>(v[0].At(r)), static_cast<float>(v[1].At(r)), static_cast<float>(v[2].At(r)));
      }
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

Vec2 SimSource::GroundOf(size_t i) const {
  return Apply(CanvasFromFrame(plan_, poses_[i]), Vec2((plan_.frame_width - 1.0) / 2, (plan_.frame_height - 1.0) / 2));
}

Vec2 SimSource::GpsErrorM(double f, cv::RNG* rng) const {
  const double turn = 2.0 * M_PI * f / 200.0;  // the bias turns once per 200 frames
  const double east = plan_.gps_bias_m * std::cos(turn) + rng->gaussian(plan_.gps_noise_m);
  const double north = plan_.gps_bias_m * std::sin(turn) + rng->gaussian(plan_.gps_noise_m);
  return Vec2(east, north);
}

void SimSource::SimulateGps(size_t i, cv::Size size, SimTruth* truth) const {
  const Vec2 ground = Apply(truth->canvas_from_frame, Vec2((size.width - 1.0) / 2, (size.height - 1.0) / 2));
  truth->true_position = CanvasToLatLon(plan_, canvas_.size(), ground);
  // Per-frame generator (frame i's fix does not depend on the frames before), plus a slowly turning bias.
  cv::RNG rng(plan_.seed * 7919ULL + i + 1);
  const Vec2 error = GpsErrorM(static_cast<double>(i), &rng);
  truth->gps_position = CanvasToLatLon(
      plan_, canvas_.size(), ground + Vec2(error.x() / plan_.metres_per_px, -error.y() / plan_.metres_per_px));
  truth->gps_altitude_m = plan_.flight_altitude_m * truth->pose.altitude;
  // Compass heading of the direction of flight (frame +x): canvas +x is east, +y south, so yaw 0 is 90 deg.
  truth->gps_heading_deg = Wrap360(90.0 + truth->pose.yaw_deg + rng.gaussian(plan_.heading_noise_deg));
}

SimFix SimSource::FixAt(double t_s, uint64_t draw) const {
  const size_t last = poses_.size() - 1;
  const double f = t_s / plan_.frame_interval_s;
  const double clamped = std::clamp(f, 0.0, static_cast<double>(last));
  const size_t i = std::min(static_cast<size_t>(std::floor(clamped)), last);
  const size_t j = std::min(i + 1, last);
  const double w = clamped - static_cast<double>(i);
  const SimPose& a = poses_[i];
  const SimPose& b = poses_[j];
  SimFix fix;
  cv::RNG attitude(plan_.seed * 104729ULL + draw + 1);
  fix.roll_deg = Lerp(a.roll_deg, b.roll_deg, w) + attitude.gaussian(plan_.attitude_noise_deg);
  fix.pitch_deg = Lerp(a.pitch_deg, b.pitch_deg, w) + attitude.gaussian(plan_.attitude_noise_deg);
  fix.altitude_m = plan_.flight_altitude_m * Lerp(a.altitude, b.altitude, w);
  const Vec2 ga = GroundOf(i), gb = GroundOf(j);
  const Vec2 ground = ga + (gb - ga) * w;
  fix.true_position = CanvasToLatLon(plan_, canvas_.size(), ground);
  if (f >= 0 && f <= static_cast<double>(last) && j > i) {  // flying, not hovering before or after the flight
    const Vec2 v = (gb - ga) * (plan_.metres_per_px / plan_.frame_interval_s);
    fix.east_mps = v.x();
    fix.north_mps = -v.y();
  }
  const double nearest = std::round(f);
  if (std::abs(f - nearest) < 1e-9 && nearest >= 0 && nearest <= static_cast<double>(last)) {
    SimTruth t;  // a frame's instant: its own fix
    const auto k = static_cast<size_t>(nearest);
    t.pose = poses_[k];
    t.canvas_from_frame = CanvasFromFrame(plan_, t.pose);
    SimulateGps(k, cv::Size(plan_.frame_width, plan_.frame_height), &t);
    fix.gps_position = t.gps_position;
    fix.heading_deg = t.gps_heading_deg;
    return fix;
  }
  cv::RNG rng(plan_.seed * 15485863ULL + draw + 1);
  const Vec2 error = GpsErrorM(f, &rng);
  fix.gps_position = CanvasToLatLon(plan_, canvas_.size(),
                                    ground + Vec2(error.x() / plan_.metres_per_px, -error.y() / plan_.metres_per_px));
  const double yaw = a.yaw_deg + std::remainder(b.yaw_deg - a.yaw_deg, 360.0) * w;  // the short way round
  fix.heading_deg = Wrap360(90.0 + yaw + rng.gaussian(plan_.heading_noise_deg));
  return fix;
}

cv::Mat SimSource::Project(const cv::Mat& src, const Mat3& src_from_frame) const {
  cv::Mat frame;
  if (ideal_from_frame_.empty()) {
    // WARP_INVERSE_MAP: the matrix maps destination (frame) pixels to source pixels, exactly the truth's direction.
    cv::warpPerspective(src, frame, ToCv(src_from_frame), cv::Size(plan_.frame_width, plan_.frame_height),
                        cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REFLECT);
    return frame;
  }
  cv::Mat src_from_pixel;
  cv::perspectiveTransform(ideal_from_frame_, src_from_pixel, ToCv(src_from_frame));
  cv::remap(src, frame, src_from_pixel, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  return frame;
}

// The light the sun adds and the drone takes in frame i: the opposition hotspot around the antisolar point and the
// drone's shadow on it, a CV_32FC3 factor per pixel (empty when the plan has neither). The antisolar direction is
// fixed on the ground, so in the frame it turns with the yaw (the camera's small tilts are left out).
cv::Mat SimSource::SunLight(const SimPose& pose) const {
  if (!(plan_.hotspot > 0) && !(plan_.shadow > 0)) return {};
  constexpr double kDeg = M_PI / 180.0;
  const PinholeCamera camera = plan_.Camera();
  const double off_nadir = (90.0 - plan_.sun_elevation_deg) * kDeg;
  const double towards = (plan_.sun_azimuth_deg + 180.0 - pose.yaw_deg) * kDeg;  // in the frame, from +x to +y
  const Eigen::Vector3d antisolar(std::sin(off_nadir) * std::cos(towards), std::sin(off_nadir) * std::sin(towards),
                                  std::cos(off_nadir));
  const double f = camera.focal_px;
  const Vec2 shadow_px(camera.cx + f * antisolar.x() / antisolar.z(), camera.cy + f * antisolar.y() / antisolar.z());
  const double width = plan_.hotspot_width_deg * kDeg;
  cv::Mat light(plan_.frame_height, plan_.frame_width, CV_32FC3);
  for (int y = 0; y < light.rows; ++y)
    for (int x = 0; x < light.cols; ++x) {
      const Eigen::Vector3d ray = Eigen::Vector3d((x - camera.cx) / f, (y - camera.cy) / f, 1.0).normalized();
      const double angle = std::acos(std::clamp(ray.dot(antisolar), -1.0, 1.0));
      double v = 1.0 + plan_.hotspot * std::exp(-angle * angle / (2 * width * width));
      const double d = std::hypot(x - shadow_px.x(), y - shadow_px.y());
      v *= 1.0 - plan_.shadow * std::clamp(plan_.shadow_radius_px + 0.5 - d, 0.0, 1.0);
      light.at<cv::Vec3f>(y, x) = cv::Vec3f::all(static_cast<float>(v));
    }
  return light;
}

// Vignetting, exposure and white balance, the sun's hotspot and the drone's shadow, sensor noise. The falloff is
// applied after the motion blur, not before as in a real camera: it is smooth, so over a blur of a few pixels the order
// changes nothing measurable.
void SimSource::Expose(size_t i, cv::Mat* frame) {
  const SimPose& pose = poses_[i];
  const auto& wb = pose.white_balance;
  const cv::Mat sun = SunLight(pose);
  const bool colour = !falloff_.empty() || !sun.empty() || wb[0] != 1.0 || wb[1] != 1.0 || wb[2] != 1.0;
  if (!colour && pose.gain == 1.0 && pose.offset == 0.0 && !(plan_.noise_sigma > 0)) return;
  cv::Mat& f = exposure_;
  if (colour) {
    frame->convertTo(f, CV_32F);
    if (!falloff_.empty()) cv::multiply(f, falloff_, f);
    if (!sun.empty()) cv::multiply(f, sun, f);
    cv::multiply(f, cv::Scalar(pose.gain * wb[0], pose.gain * wb[1], pose.gain * wb[2]), f);
    f += cv::Scalar::all(pose.offset);
  } else {
    frame->convertTo(f, CV_32F, pose.gain, pose.offset);  // the flights made before white balance, byte for byte
  }
  if (plan_.noise_sigma > 0) {
    // Per-frame generator: frame i's noise does not depend on which frames were rendered before.
    cv::RNG rng(plan_.seed * 1000003ULL + i + 1);
    noise_.create(f.size(), f.type());
    rng.fill(noise_, cv::RNG::NORMAL, 0.0, plan_.noise_sigma);
    f += noise_;
  }
  f.convertTo(*frame, CV_8U);
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
  cv::Mat frame = Project(src, src_from_frame);

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
  Expose(i, &frame);
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
  // Live telemetry: the frame comes when the stream has reached its delivery, stamped on the stream's clock.
  frame->timestamp_ns = link_ ? link_->DeliverFrame(next_) : LiveCameraTime(next_);
  frame->source_name = FrameName(next_);
  frame->original_size = image.size();
  frame->image = std::move(image);
  frame->decode_scale = 1.0;
  // As a camera's EXIF GPS would carry it; live, the position comes from the telemetry.
  if (plan_.gps != 0 && !link_ && !(plan_.live_camera != 0 && options_.live_link)) {
    frame->metadata.latitude_deg = truth_.gps_position.lat_deg;
    frame->metadata.longitude_deg = truth_.gps_position.lon_deg;
    frame->metadata.relative_altitude_m = truth_.gps_altitude_m;
    frame->metadata.flight_yaw_deg = truth_.gps_heading_deg;
  }
  ++next_;
  return Status::kOk;
}

int64_t SimSource::LiveCameraTime(size_t i) {
  if (plan_.live_camera == 0 || !options_.live_link) return MonotonicNs();
  if (i == 0 || live_start_ns_ == 0) {
    live_start_ns_ = MonotonicNs() - std::llround(FrameTime(i) * 1e9);
    if (plan_.start_unix_s > 0) {  // the wall clock's moment on the monotonic clock
      const double until_s = plan_.start_unix_s -
                             std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
      live_start_ns_ = MonotonicNs() + std::llround(until_s * 1e9);
    }
  }
  const int64_t due = live_start_ns_ + std::llround(FrameTime(i) * 1e9);
  const int64_t wait = due - MonotonicNs();
  if (wait > 0) std::this_thread::sleep_for(std::chrono::nanoseconds(wait));
  return due;
}

void SimSource::Close() {
  link_.reset();
  canvas_.release();
  levels_.clear();
  exposure_.release();
  noise_.release();
}

}  // namespace uavm::hal
