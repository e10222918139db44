// The lens: chosen once from the first frame, undistorting every working copy and its features; after the end of
// the flight's calibration, recorded in camera.yaml and report.json.
#include "core/pipeline/work_lens.h"

#include <spdlog/spdlog.h>

#include <cstdio>

#include "core/lens/lens_database.h"

namespace uavm {

const Undistorter& WorkLens::For(const Frame& frame, cv::Size work_size) const {
  std::call_once(once_, [&] {
    choice_ = ChooseCamera(options_, frame.metadata, frame.original_size);
    original_size_ = frame.original_size;
    work_ = Undistorter(choice_.camera.Resized(work_size.width, work_size.height));
    spdlog::info("lens: {} ({}{}{}), focal {:.0f} px from {}; {:+.3f} at the half-diagonal", choice_.source,
                 choice_.camera.distortion.IsZero() ? "undistorted frames" : "frames undistorted",
                 choice_.detail.empty() ? "" : "; ", choice_.detail, choice_.camera.focal_px, choice_.focal_from,
                 choice_.camera.RadialDistortionAtHalfDiagonal());
  });
  static const Undistorter kNone;
  return frame.original_size == original_size_ ? work_ : kNone;
}

std::jthread PreloadLensDatabase(const CameraOptions& options) {
  if (!options.database || options.Configured()) return {};
  return std::jthread([] { (void)LensDatabaseAvailable(); });
}

PinholeCamera FinalCamera(const WorkLens& lens, const LensCalibration& calibration) {
  PinholeCamera c = lens.choice().camera;
  if (calibration.accepted || calibration.dropped) c.distortion = calibration.distortion;
  return c;
}

std::string CameraYaml(const WorkLens& lens, const LensCalibration& calibration) {
  if (!lens.chosen()) return {};
  const PinholeCamera c = FinalCamera(lens, calibration);
  std::string source = calibration.accepted ? "self-calibrated" : calibration.dropped ? "none" : lens.choice().source;
  if (calibration.dropped) source += " (the " + lens.choice().source + " lens was dropped)";
  char buf[1024];
  std::snprintf(buf, sizeof(buf),
                "# The lens the session's frames were undistorted with: transforms.csv maps *undistorted* pixels,\n"
                "# ideal = UndistortPixel(recorded) (Brown-Conrady, OpenCV's convention, normalised by focal_px).\n"
                "camera:\n  width: %d\n  height: %d\n  focal_px: %.10g\n  cx: %.10g\n  cy: %.10g\n"
                "  k1: %.10g\n  k2: %.10g\n  p1: %.10g\n  p2: %.10g\n"
                "source: %s\nfocal_from: %s\n",
                c.width, c.height, c.focal_px, c.cx, c.cy, c.distortion.k1, c.distortion.k2, c.distortion.p1,
                c.distortion.p2, source.c_str(), lens.choice().focal_from.c_str());
  return buf;
}

nlohmann::json LensJson(const WorkLens& lens, const LensCalibration& cal) {
  const CameraChoice& choice = lens.choice();
  nlohmann::json j = {
      {"prepared_with", choice.source},
      {"detail", choice.detail},
      {"focal_px", choice.camera.focal_px},
      {"focal_from", choice.focal_from},
      {"prepared_distortion_at_half_diagonal", choice.camera.RadialDistortionAtHalfDiagonal()},
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
        {"frames", cal.frames},
        {"rematched_edges", cal.rematched_edges},
        {"first_distortion_at_half_diagonal", cal.first_at_half_diagonal},
        {"correction_holdout_rms_px", {cal.residual_holdout_without_px, cal.residual_holdout_with_px}},
        {"final_points",
         {{"rematched_kept", cal.rematched_points_kept},
          {"holdout_rms_px_flight", cal.holdout_flight_points_px},
          {"holdout_rms_px_rematched", cal.holdout_rematched_points_px}}},
        {"seconds", cal.seconds}}}};
  const PinholeCamera final_camera = FinalCamera(lens, cal);
  j["final"] = {{"k1", final_camera.distortion.k1},
                {"k2", final_camera.distortion.k2},
                {"p1", final_camera.distortion.p1},
                {"p2", final_camera.distortion.p2},
                {"distortion_at_half_diagonal", final_camera.RadialDistortionAtHalfDiagonal()}};
  return j;
}

}  // namespace uavm
