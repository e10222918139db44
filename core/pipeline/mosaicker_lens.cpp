// The lens: chosen once from the first frame, undistorting every working copy and its features, calibrated at the
// end of the flight, recorded in camera.yaml and report.json, and undone on every part the compositor loads.
#include <spdlog/spdlog.h>

#include <cstdio>
#include <nlohmann/json.hpp>

#include "core/lens/camera_setup.h"
#include "core/pipeline/canvas_load.h"
#include "core/pipeline/mosaicker.h"

namespace uavm {

const Undistorter& Mosaicker::WorkLens(const Frame& frame, cv::Size work_size) const {
  std::call_once(lens_once_, [&] {
    lens_choice_ = ChooseCamera(options_.camera, frame.metadata, frame.original_size);
    lens_original_size_ = frame.original_size;
    work_lens_ = Undistorter(lens_choice_.camera.Resized(work_size.width, work_size.height));
    spdlog::info("lens: {} ({}{}{}), focal {:.0f} px from {}; {:+.3f} at the half-diagonal", lens_choice_.source,
                 lens_choice_.camera.distortion.IsZero() ? "undistorted frames" : "frames undistorted",
                 lens_choice_.detail.empty() ? "" : "; ", lens_choice_.detail, lens_choice_.camera.focal_px,
                 lens_choice_.focal_from, lens_choice_.camera.RadialDistortionAtHalfDiagonal());
  });
  // A frame of another size than the first (a second camera?) is used as recorded.
  static const Undistorter kNone;
  return frame.original_size == lens_original_size_ ? work_lens_ : kNone;
}

void Mosaicker::HandEngineTheCamera(cv::Size work_size) {
  if (engine_has_camera_ || work_lens_.camera().width != work_size.width ||
      work_lens_.camera().height != work_size.height)
    return;
  engine_.SetCamera(work_lens_.camera(), lens_choice_.source == "configuration");
  engine_has_camera_ = true;
}

PinholeCamera Mosaicker::FinalCamera() const {
  PinholeCamera c = lens_choice_.camera;
  if (solution_.lens.accepted || solution_.lens.dropped) c.distortion = solution_.lens.distortion;
  return c;
}

bool Mosaicker::WriteCameraYaml(std::string* error) const {
  if (lens_original_size_.width <= 0) return true;  // no frame was prepared
  const PinholeCamera c = FinalCamera();
  const std::string source = solution_.lens.accepted  ? "self-calibrated"
                             : solution_.lens.dropped ? "none (the " + lens_choice_.source + " lens was dropped)"
                                                      : lens_choice_.source;
  char buf[1024];
  std::snprintf(buf, sizeof(buf),
                "# The lens the session's frames were undistorted with: transforms.csv maps *undistorted* pixels,\n"
                "# ideal = UndistortPixel(recorded) (Brown-Conrady, OpenCV's convention, normalised by focal_px).\n"
                "camera:\n  width: %d\n  height: %d\n  focal_px: %.10g\n  cx: %.10g\n  cy: %.10g\n"
                "  k1: %.10g\n  k2: %.10g\n  p1: %.10g\n  p2: %.10g\n"
                "source: %s\nfocal_from: %s\n",
                c.width, c.height, c.focal_px, c.cx, c.cy, c.distortion.k1, c.distortion.k2, c.distortion.p1,
                c.distortion.p2, source.c_str(), lens_choice_.focal_from.c_str());
  return WriteFileAtomic(paths_.Join("camera.yaml"), buf, error);
}

nlohmann::json Mosaicker::LensJson() const {
  const LensCalibration& cal = solution_.lens;
  nlohmann::json j = {
      {"prepared_with", lens_choice_.source},
      {"detail", lens_choice_.detail},
      {"focal_px", lens_choice_.camera.focal_px},
      {"focal_from", lens_choice_.focal_from},
      {"prepared_distortion_at_half_diagonal", lens_choice_.camera.RadialDistortionAtHalfDiagonal()},
      {"self_calibration",
       {{"tried", cal.tried},
        {"accepted", cal.accepted},
        {"prepared_lens_dropped", cal.dropped},
        {"why", cal.why},
        {"k1", cal.distortion.k1},
        {"k2", cal.distortion.k2},
        {"distortion_at_half_diagonal", cal.distortion_at_half_diagonal},
        {"holdout_rms_px_without", cal.holdout_without_px},
        {"holdout_rms_px_with", cal.holdout_with_px},
        {"holdout_points", cal.holdout_points},
        {"holdout_edges", cal.holdout_edges},
        {"holdout_gain_t", cal.holdout_gain_t},
        {"halves_distortion_at_half_diagonal", {cal.half_a_at_half_diagonal, cal.half_b_at_half_diagonal}},
        {"correspondences", cal.used},
        {"rematched_edges", cal.rematched_edges},
        {"first_distortion_at_half_diagonal", cal.first_at_half_diagonal},
        {"correction_holdout_rms_px", {cal.residual_holdout_without_px, cal.residual_holdout_with_px}},
        {"final_points",
         {{"rematched_kept", cal.rematched_points_kept},
          {"holdout_rms_px_flight", cal.holdout_flight_points_px},
          {"holdout_rms_px_rematched", cal.holdout_rematched_points_px}}},
        {"seconds", cal.seconds}}}};
  const PinholeCamera final_camera = FinalCamera();
  j["final"] = {{"k1", final_camera.distortion.k1},
                {"k2", final_camera.distortion.k2},
                {"p1", final_camera.distortion.p1},
                {"p2", final_camera.distortion.p2},
                {"distortion_at_half_diagonal", final_camera.RadialDistortionAtHalfDiagonal()}};
  return j;
}

FramePart Mosaicker::LoadIdealPart(int id, const CanvasLoad& how, const cv::Rect& need) const {
  const FrameState& f = frames_[static_cast<size_t>(id)];
  PinholeCamera lens = FinalCamera();
  if (lens.distortion.IsZero() || f.original_size != lens_original_size_)
    return LoadCanvasPart(f.stored_file, how, need);
  // The recorded pixels the ideal part needs, decoded and resampled onto the ideal grid.
  lens = lens.Resized(how.size.width, how.size.height);
  const cv::Rect want = need & cv::Rect(cv::Point(0, 0), how.size);
  FramePart recorded = LoadCanvasPart(f.stored_file, how, RecordedRectFor(lens, want));
  if (recorded.image.empty() || want.empty()) return recorded;
  return {UndistortPart(lens, recorded.image, recorded.origin, want), cv::Point2d(want.x, want.y)};
}

}  // namespace uavm
