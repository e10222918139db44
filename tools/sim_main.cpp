// uavmosaic-sim: writes a simulated flight with ground truth (see tools/sim_writer.h for the layout).
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>

#include "tools/sim_writer.h"

int main(int argc, char** argv) {
  CLI::App app{"Simulated drone flight over an image, with ground truth"};
  uavm::hal::SimOptions options;
  options.live_link = false;  // the plan's mavlink_udp is for --source sim:; here the telemetry goes to flight.tlog
  std::string out;
  app.add_option("--plan", options.plan_path, "flight plan YAML (keys: hal/sim/sim_plan.h)")->required();
  app.add_option("--canvas", options.canvas_path, "image to fly over (overrides the plan's canvas key)");
  app.add_option("--out", out,
                 "output folder: images/, gt.csv, gt_camera.yaml, gt_exposure.csv, plan.yaml (with gps: geo.txt, "
                 "geo_truth.txt, flight.tlog)")
      ->required();
  app.add_option("--frames", options.max_frames, "stop after N frames (0 = whole flight)")
      ->check(CLI::NonNegativeNumber);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }
  uavm::hal::SimSource source(options);
  std::string error;
  if (source.Open(&error) != uavm::hal::Status::kOk) {
    spdlog::error("{}", error);
    // A plan that parses but is wrong is a bad argument; a missing file is an unreadable input.
    return error.find("cannot read") != std::string::npos ? 3 : 2;
  }
  if (!uavm::tools::WriteSimFlight(&source, out, options.max_frames, &error)) {
    spdlog::error("{}", error);
    return 4;
  }
  spdlog::info("wrote {} frames to {}", source.NumFrames(), out);
  return 0;
}
