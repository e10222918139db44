// uavmosaic-eval: accuracy of a session against simulator ground truth, or an image-only score of a mosaic.
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <regex>

#include "core/eval/evaluator.h"
#include "core/eval/image_score.h"
#include "hal/sim/sim_plan.h"

namespace fs = std::filesystem;

namespace {

constexpr int kBadArgs = 2;
constexpr int kUnreadable = 3;

int RunSession(const std::string& session, const std::string& gt_path, std::string frame_size,
               const std::string& json_path) {
  using namespace uavm;
  std::string text, err;
  std::vector<TransformRow> rows;
  const std::string transforms = fs::is_directory(session) ? session + "/transforms.csv" : session;
  if (!ReadTextFile(transforms, &text, &err) || !ParseTransformsCsv(text, &rows, &err)) {
    spdlog::error("{}: {}", transforms, err);
    return kUnreadable;
  }
  std::vector<eval::GtRow> gt;
  if (!ReadTextFile(gt_path, &text, &err) || !eval::ParseGroundTruthCsv(text, &gt, &err)) {
    spdlog::error("{}: {}", gt_path, err);
    return kUnreadable;
  }
  cv::Size size;
  if (!frame_size.empty()) {
    std::smatch m;
    if (!std::regex_match(frame_size, m, std::regex(R"((\d+)x(\d+))"))) {
      spdlog::error("--frame-size must be WxH");
      return kBadArgs;
    }
    size = {std::stoi(m[1]), std::stoi(m[2])};
  } else {
    // The simulator writes its effective plan next to gt.csv: the frame size comes from there.
    hal::SimPlan plan;
    const std::string plan_path = (fs::path(gt_path).parent_path() / "plan.yaml").string();
    if (!hal::LoadSimPlanFile(plan_path, &plan, &err)) {
      spdlog::error("frame size unknown (give --frame-size WxH): {}", err);
      return kUnreadable;
    }
    size = {plan.frame_width, plan.frame_height};
  }
  eval::EvalResult result, floor;
  if (!eval::EvaluateSession(rows, gt, size, &result, &err)) {
    spdlog::error("evaluation: {}", err);
    return kUnreadable;
  }
  if (!eval::EvaluateSession(eval::AffineFloorSession(gt), gt, size, &floor, &err)) {
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
  if (!json_path.empty()) {
    std::ofstream out(json_path);
    out << eval::ToJson(result, &floor).dump(2) << "\n";
    if (!out) {
      spdlog::error("cannot write {}", json_path);
      return 4;
    }
  }
  return 0;
}

int RunImage(const std::string& mosaic_path, const std::string& canvas_path, const std::string& json_path) {
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
  if (!json_path.empty()) {
    nlohmann::json j{{"matches", score.matches},
                     {"inliers", score.inliers},
                     {"median_px", score.median_px},
                     {"p90_px", score.p90_px}};
    std::ofstream out(json_path);
    out << j.dump(2) << "\n";
    if (!out) return 4;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Evaluate a uavmosaic session against simulator ground truth"};
  std::string session, gt, frame_size, json;
  app.add_option("--session", session, "session directory (or its transforms.csv)");
  app.add_option("--gt", gt, "gt.csv written by uavmosaic-sim");
  app.add_option("--frame-size", frame_size, "WxH of the original frames (default: plan.yaml next to gt.csv)");
  app.add_option("--json", json, "write the figures as JSON");
  auto* image = app.add_subcommand("image", "score a mosaic image against the canvas (SIFT + RANSAC affine)");
  std::string mosaic, canvas, image_json;
  image->add_option("--mosaic", mosaic, "mosaic image (alpha = flown area)")->required();
  image->add_option("--canvas", canvas, "the canvas the flight was simulated over")->required();
  image->add_option("--json", image_json, "write the figures as JSON");
  app.require_subcommand(0, 1);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : kBadArgs;
  }
  if (image->parsed()) return RunImage(mosaic, canvas, image_json);
  if (session.empty() || gt.empty()) {
    std::fprintf(stderr, "--session and --gt are required (or the 'image' subcommand)\n%s", app.help().c_str());
    return kBadArgs;
  }
  return RunSession(session, gt, frame_size, json);
}
