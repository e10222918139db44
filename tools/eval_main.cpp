// uavmosaic-eval: accuracy of a session against simulator ground truth, or an image-only score of a mosaic.
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <regex>

#include "core/eval/evaluator.h"
#include "core/eval/image_score.h"
#include "core/eval/photometric.h"
#include "hal/sim/sim_plan.h"
#include "hal/sim/sim_source.h"

namespace fs = std::filesystem;

namespace {

constexpr int kBadArgs = 2;
constexpr int kUnreadable = 3;

struct SessionArgs {
  std::string session, gt, frame_size, json;
  std::string session_camera;  // a file with a `camera` block (gt_camera.yaml's layout): the session's lens model
  std::string canvas;          // default: the canvas of plan.yaml beside gt.csv
  bool photometric = true;
  double sigma_fraction = uavm::eval::PhotometricOptions{}.sigma_footprint_fraction;
};

// The frame size: --frame-size, else the plan the simulator wrote beside gt.csv. `plan` gets that plan when read.
int FrameSize(const SessionArgs& a, cv::Size* size, uavm::hal::SimPlan* plan, bool* have_plan) {
  std::string err;
  const std::string plan_path = (fs::path(a.gt).parent_path() / "plan.yaml").string();
  *have_plan = uavm::hal::LoadSimPlanFile(plan_path, plan, &err);
  if (!a.frame_size.empty()) {
    std::smatch m;
    if (!std::regex_match(a.frame_size, m, std::regex(R"((\d+)x(\d+))"))) {
      spdlog::error("--frame-size must be WxH");
      return kBadArgs;
    }
    *size = {std::stoi(m[1]), std::stoi(m[2])};
    return 0;
  }
  if (!*have_plan) {
    spdlog::error("frame size unknown (give --frame-size WxH): {}", err);
    return kUnreadable;
  }
  *size = {plan->frame_width, plan->frame_height};
  return 0;
}

// The lens models: the truth's from gt_camera.yaml beside gt.csv (none for older flights), the session's from
// --session-camera.
bool Cameras(const SessionArgs& a, uavm::eval::EvalOptions* options) {
  using namespace uavm;
  std::string err, text;
  std::optional<eval::GtCamera> truth;
  if (!eval::LoadGroundTruthCamera(a.gt, &truth, &err)) {
    spdlog::error("{}", err);
    return false;
  }
  if (truth) options->truth_camera = truth->camera;
  if (a.session_camera.empty()) return true;
  PinholeCamera camera;
  if (!ReadTextFile(a.session_camera, &text, &err) || !eval::ParseCameraBlock(text, &camera, &err)) {
    spdlog::error("{}: {}", a.session_camera, err);
    return false;
  }
  options->session_camera = camera;
  return true;
}

// The low-frequency brightness error of the session's mosaic.png (core/eval/photometric.h): its pixels relate to the
// transforms' mosaic pixels by the quick-look's reduction (report.json's mosaic size). Null when it cannot be made.
nlohmann::json Photometric(const SessionArgs& a, const uavm::hal::SimPlan* plan,
                           const std::vector<uavm::eval::GtRow>& gt, cv::Size frame_size,
                           const uavm::Mat3& canvas_from_mosaic) {
  using namespace uavm;
  const fs::path dir = fs::is_directory(a.session) ? fs::path(a.session) : fs::path(a.session).parent_path();
  std::string text, err;
  nlohmann::json report;
  if (!ReadTextFile((dir / "report.json").string(), &text, &err) ||
      !(report = nlohmann::json::parse(text, nullptr, false)).contains("mosaic")) {
    spdlog::warn("photometric: no mosaic size in {}/report.json: skipped", dir.string());
    return nullptr;
  }
  const cv::Mat mosaic = cv::imread((dir / "mosaic.png").string(), cv::IMREAD_UNCHANGED);
  const std::string canvas_path = !a.canvas.empty() ? a.canvas : plan != nullptr ? plan->canvas : "";
  cv::Mat canvas =
      canvas_path.empty() ? cv::Mat() : cv::imread(canvas_path, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
  const double width = report["mosaic"].value("width", 0.0), height = report["mosaic"].value("height", 0.0);
  if (mosaic.empty() || canvas.empty() || !(width > 0 && height > 0)) {
    spdlog::warn("photometric: mosaic.png, the canvas (--canvas) or the mosaic size missing: skipped");
    return nullptr;
  }
  if (plan != nullptr) hal::PaintSimWater(*plan, &canvas);  // the canvas as the frames showed it
  eval::PhotometricOptions options;
  options.sigma_footprint_fraction = a.sigma_fraction;
  eval::PhotometricResult r;
  const Mat3 mosaic_from_image = ResizeMap(width / mosaic.cols, height / mosaic.rows);
  if (!eval::PhotometricError(mosaic, mosaic_from_image, canvas, canvas_from_mosaic,
                              eval::FootprintSidePx(gt, frame_size), &r, &err, options)) {
    spdlog::warn("{}: skipped", err);
    return nullptr;
  }
  std::printf("low-frequency brightness error after one gain per channel: %.3f %% RMS (sigma %.1f canvas px)\n",
              r.rms_percent, r.sigma_canvas_px);
  return eval::ToJson(r);
}

int RunSession(const SessionArgs& a) {
  using namespace uavm;
  std::string text, err;
  std::vector<TransformRow> rows;
  const std::string transforms = fs::is_directory(a.session) ? a.session + "/transforms.csv" : a.session;
  if (!ReadTextFile(transforms, &text, &err) || !ParseTransformsCsv(text, &rows, &err)) {
    spdlog::error("{}: {}", transforms, err);
    return kUnreadable;
  }
  std::vector<eval::GtRow> gt;
  if (!ReadTextFile(a.gt, &text, &err) || !eval::ParseGroundTruthCsv(text, &gt, &err)) {
    spdlog::error("{}: {}", a.gt, err);
    return kUnreadable;
  }
  cv::Size size;
  hal::SimPlan plan;
  bool have_plan = false;
  if (const int rc = FrameSize(a, &size, &plan, &have_plan); rc != 0) return rc;
  eval::EvalOptions options;
  if (!Cameras(a, &options)) return kUnreadable;
  eval::EvalResult result, floor;
  if (!eval::EvaluateSession(rows, gt, size, &result, &err, options)) {
    spdlog::error("evaluation: {}", err);
    return kUnreadable;
  }
  // The floor of an affine model over undistorted pixels: the lens is not the affine model's fault.
  eval::EvalOptions floor_options = options;
  floor_options.session_camera = options.truth_camera;
  if (!eval::EvaluateSession(eval::AffineFloorSession(gt), gt, size, &floor, &err, floor_options)) {
    spdlog::error("affine floor: {}", err);
    return kUnreadable;
  }
  std::printf("frames %d, registered %d (%.1f %%)\n", result.frames, result.registered,
              100.0 * result.registered_share);
  std::printf("%-22s %10s %10s\n", "error (frame px)", "rms", "max");
  std::printf("%-22s %10.4f %10.4f\n", "session", result.rms_px, result.max_px);
  std::printf("%-22s %10.4f %10.4f\n", "affine floor", floor.rms_px, floor.max_px);
  std::printf("drift: first third %.4f, last third %.4f, ratio %.3f, slope %.4f px per 1000 canvas px\n",
              result.first_third_rms_px, result.last_third_rms_px, result.drift_ratio, result.drift_slope_px_per_kpx);
  nlohmann::json j = eval::ToJson(result, &floor);
  if (options.truth_camera)
    j["truth_distortion_at_half_diagonal"] = options.truth_camera->RadialDistortionAtHalfDiagonal();
  if (a.photometric) {
    const nlohmann::json photometric = Photometric(a, have_plan ? &plan : nullptr, gt, size, result.canvas_from_mosaic);
    if (!photometric.is_null()) j["photometric"] = photometric;
  }
  if (!a.json.empty()) {
    std::ofstream out(a.json);
    out << j.dump(2) << "\n";
    if (!out) {
      spdlog::error("cannot write {}", a.json);
      return 4;
    }
  }
  return 0;
}

// The photometric error of a mosaic placed on the canvas by the image score's affine (any tool's output). A mosaic
// without alpha (cv::Stitcher's) is taken as flown wherever it is not pure black.
nlohmann::json ImagePhotometric(const cv::Mat& mosaic, const cv::Mat& canvas, const uavm::Mat3& canvas_from_mosaic,
                                double footprint_px) {
  using namespace uavm;
  cv::Mat bgra = mosaic;
  if (mosaic.channels() == 3) {
    cv::Mat grey, alpha;
    cv::cvtColor(mosaic, grey, cv::COLOR_BGR2GRAY);
    cv::compare(grey, 0, alpha, cv::CMP_GT);
    cv::cvtColor(mosaic, bgra, cv::COLOR_BGR2BGRA);
    cv::insertChannel(alpha, bgra, 3);
  }
  eval::PhotometricResult r;
  std::string err;
  if (!eval::PhotometricError(bgra, Mat3::Identity(), canvas, canvas_from_mosaic, footprint_px, &r, &err)) {
    spdlog::warn("{}: skipped", err);
    return nullptr;
  }
  std::printf("low-frequency brightness error after one gain per channel: %.3f %% RMS (sigma %.1f canvas px)\n",
              r.rms_percent, r.sigma_canvas_px);
  return eval::ToJson(r);
}

int RunImage(const std::string& mosaic_path, const std::string& canvas_path, const std::string& json_path,
             double footprint_px) {
  const cv::Mat mosaic = cv::imread(mosaic_path, cv::IMREAD_UNCHANGED | cv::IMREAD_IGNORE_ORIENTATION);
  const cv::Mat canvas = cv::imread(canvas_path, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
  if (mosaic.empty() || canvas.empty()) {
    spdlog::error("cannot read {}", mosaic.empty() ? mosaic_path : canvas_path);
    return kUnreadable;
  }
  uavm::eval::ImageScore score;
  std::string err;
  if (!uavm::eval::ScoreMosaicImage(mosaic, canvas, &score, &err)) {
    spdlog::error("image score: {}", err);
    return kUnreadable;
  }
  std::printf("matches %d, inliers %d, residual median %.3f px, p90 %.3f px (canvas pixels)\n", score.matches,
              score.inliers, score.median_px, score.p90_px);
  const nlohmann::json photometric =
      footprint_px > 0 ? ImagePhotometric(mosaic, canvas, score.canvas_from_mosaic, footprint_px) : nullptr;
  if (!json_path.empty()) {
    nlohmann::json j{{"matches", score.matches},
                     {"inliers", score.inliers},
                     {"median_px", score.median_px},
                     {"p90_px", score.p90_px}};
    if (!photometric.is_null()) j["photometric"] = photometric;
    std::ofstream out(json_path);
    out << j.dump(2) << "\n";
    if (!out) return 4;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Evaluate a uavmosaic session against simulator ground truth"};
  SessionArgs a;
  app.add_option("--session", a.session, "session directory (or its transforms.csv)");
  app.add_option("--gt", a.gt, "gt.csv written by uavmosaic-sim (gt_camera.yaml beside it: the true lens)");
  app.add_option("--frame-size", a.frame_size, "WxH of the original frames (default: plan.yaml next to gt.csv)");
  app.add_option("--json", a.json, "write the figures as JSON");
  app.add_option("--session-camera", a.session_camera,
                 "the session's lens (a `camera` block as in gt_camera.yaml): its transforms map undistorted pixels");
  app.add_option("--canvas", a.canvas, "canvas for the photometric error (default: plan.yaml's canvas)");
  app.add_option("--photometric-sigma", a.sigma_fraction,
                 "Gaussian sigma of the photometric error, in frame footprints (default 0.25)")
      ->check(CLI::Range(0.01, 4.0));
  app.add_flag("!--no-photometric", a.photometric, "skip the photometric error (mosaic.png against the canvas)");
  auto* image = app.add_subcommand("image", "score a mosaic image against the canvas (SIFT + RANSAC affine)");
  std::string mosaic, canvas, image_json;
  image->add_option("--mosaic", mosaic, "mosaic image (alpha = flown area)")->required();
  image->add_option("--canvas", canvas, "the canvas the flight was simulated over")->required();
  image->add_option("--json", image_json, "write the figures as JSON");
  double footprint_px = 0;
  image
      ->add_option("--footprint-px", footprint_px,
                   "side of a frame's footprint in canvas px: also the photometric error (sigma 0.25 of it); 0 = not")
      ->check(CLI::NonNegativeNumber);
  app.require_subcommand(0, 1);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : kBadArgs;
  }
  if (image->parsed()) return RunImage(mosaic, canvas, image_json, footprint_px);
  if (a.session.empty() || a.gt.empty()) {
    std::fprintf(stderr, "--session and --gt are required (or the 'image' subcommand)\n%s", app.help().c_str());
    return kBadArgs;
  }
  return RunSession(a);
}
