// uavmosaic-onboard: thin entry point; the loop lives in app.cpp.
#include <malloc.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include "core/buffers/mat_pool.h"
#include "core/util/memory.h"
#include "firmware_app/app.h"
#include "firmware_app/flight_status.h"
#include "hal/common/camera_options.h"

namespace {

// --http and what goes with it: the live view, its tiles, its base map and how long it outlives the flight.
void AddLiveViewOptions(CLI::App* cli, uavm::app::RunConfig* config, bool* no_live_tiles) {
  cli->add_option("--http", config->http,
                  "Live view over HTTP on HOST:PORT (e.g. 0.0.0.0:8080): / (map page), /live.jpg, /status.json; "
                  "off by default");
  cli->add_option("--basemap", config->basemap,
                  "With --http: a base map under the live tiles, as an XYZ URL template the operator's browser fetches "
                  "(e.g. https://tile.openstreetmap.org/{z}/{x}/{y}.png); none by default (offline)");
  cli->add_option("--http-linger", config->http_linger_s,
                  "With --http: keep serving the finished map (tiles, status) this many seconds after the flight, or "
                  "until SIGTERM/SIGINT (a ground station that kept the URL gets the final tiles)");
  cli->add_flag("--no-live-tiles", *no_live_tiles,
                "With --http: no live tile pyramid (live_tiles/, /tiles/...); the live view shows live.jpg only");
  cli->add_option("--http-token-file", config->http_token_file,
                  "With --http: every request needs this file's access token (Authorization: Bearer TOKEN, or "
                  "?token=TOKEN); required off the loopback (e.g. a systemd credential: README, deploy)");
  cli->add_flag("--http-no-auth", config->http_no_auth,
                "With --http off the loopback: serve without a token (a trusted network only)");
  cli->add_option("--http-cert", config->http_cert_file, "With --http: serve HTTPS with this PEM certificate (chain)");
  cli->add_option("--http-key", config->http_key_file, "With --http-cert: its PEM private key");
}

// What the registration and the mosaic are made with (core's PipelineOptions; the same keys in --config).
void AddPipelineOptions(CLI::App* cli, uavm::PipelineOptions* p) {
  cli->add_option("--work-size", p->work_long_side, "Long side of the working copy used for registration, px");
  cli->add_option("--memory-budget", p->memory_budget_mib,
                  "Memory budget of the whole program, MiB; caches, pools and feature detection fit into it "
                  "(0 = none)");
  cli->add_option("--max-features", p->features.max_features, "Keypoints kept per frame");
  cli->add_option("--min-features", p->features.target_min_features,
                  "Below this many keypoints a frame is detected again at a lower contrast threshold (0 = never)");
  cli->add_option("--mosaic-scale", p->mosaic_scale,
                  "mosaic.tif resolution relative to the reference frame's original pixels (1 = full resolution)");
  cli->add_option("--quicklook-size", p->mosaic.quicklook_long_side, "Longest side of mosaic.png, px");
  cli->add_option("--bands", p->mosaic.num_bands, "Multi-band blending levels (0 = hard seams)");
  cli->add_option("--preview-every", p->preview_every, "Write live.jpg every N frames (0 = off)");
  cli->add_option("--recent", p->recent_candidates, "Recent frames matched against each new frame (K)");
  cli->add_option("--overlap-candidates", p->overlap_candidates, "Extra frames chosen by footprint overlap (M)");
  const std::map<std::string, uavm::MotionModel> models{{"affine", uavm::MotionModel::kAffine},
                                                        {"homography", uavm::MotionModel::kHomography}};
  cli->add_option("--model", p->refine.model,
                  "Per-frame map of the final solution: homography (refined projectively: tilted cameras) or affine")
      ->transform(CLI::CheckedTransformer(models, CLI::ignore_case));
  cli->add_option("--refine-seconds", p->refine.max_seconds,
                  "Time limit of the end-of-flight refinement, s (0 = none)");
  cli->add_flag(
      "--no-tiff", [p](std::int64_t) { p->write_tiff = false; }, "Do not write mosaic.tif");
}

}  // namespace

int main(int argc, char** argv) {
  using namespace uavm;
  // Resident memory must follow what the program holds: two malloc arenas (what glibc would grow to per core is
  // not needed by two working threads), and buffers of 4 MiB or more always mmapped, so that a freed detector
  // pyramid, tile or solver matrix of that size leaves the RSS instead of fragmenting a heap that only grows; the
  // heap's free pages go back every trim_heap_every frames. Smaller buffers reuse heap pages: mapped afresh, every
  // one of them faulted in and zeroed its pages on each use (256 KiB was the threshold until 2026-11-26: caliterra
  // 12 MP spent ~9 s of its ~40 s of CPU in the kernel; 4 MiB: ~3.5 s, 19.9 s wall instead of 24-27, the same phase
  // peaks within the budget; 16 MiB was faster still but passed the 256 MiB budget).
  // The end's solves map from a lower threshold (ResourceLog::EnterPhase, core/util/memory.h).
  mallopt(M_ARENA_MAX, 2);
  SetMmapThreshold(kFlightMmapThreshold);
  // Image buffers of 1 MiB and more are pooled besides (core/buffers/mat_pool.h): a phase's scale spaces and blend
  // pyramids reuse their pages rather than fault in and zero fresh ones every frame and tile.
  InstallMatPool();
  app::RunConfig config;
  std::string config_file;
  std::string log_level = "info";
  bool print_config = false;
  auto& p = config.pipeline;
  CLI::App cli{
      "uavmosaic-onboard: registers a drone's frames as they arrive and writes a mosaic, without camera poses.\n"
      "Exit codes: 0 ok; 2 bad command line or config; 3 source cannot be opened or failed mid-run; "
      "4 output directory not creatable/writable or disk full; 5 no frame could be registered."};
  bool list_cameras = false;
  cli.add_option("--source", config.source,
                 "Frame source (required): replay:DIR (images, natural filename order), replay:FILE.mp4 (video), "
                 "sim:PLAN.yaml, v4l2:/dev/videoN[?KEYS] (V4L2 camera, mmap streaming) or libcamera:N|ID[?KEYS] "
                 "(libcamera camera, N-th or by id). Camera KEYS: " +
                     hal::CameraOptionsHelp() + "; e.g. v4l2:/dev/video0?width=640&height=480&format=YUYV&fps=30");
  cli.add_option("--out", config.out_dir, "Session directory to write (created if missing; required)");
  cli.add_flag("--list-cameras", list_cameras, "Print the cameras the V4L2 and libcamera back-ends see, and exit");
  cli.add_option("--process-delay-ms", config.process_delay_ms,
                 "Testing: sleep this long per processed frame (a slow consumer: a camera's queue drops frames)")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--config", config_file, "YAML config; command-line options override it")->check(CLI::ExistingFile);
  cli.add_flag("--resume", config.resume,
               "Continue the session in --out after an interruption (kill, power loss): its journaled frames are "
               "kept and the source continues after them");
  cli.add_option("--max-frames", config.max_frames, "Stop after N frames (0 = all)")->check(CLI::NonNegativeNumber);
  cli.add_option("--stride", config.stride, "Take every N-th input of the replay (video frames or files)")
      ->check(CLI::PositiveNumber);
  cli.add_option("--replay-interval-ms", config.replay_interval_ms,
                 "A replay or simulation in real time: one input every N ms, as a camera triggering at that "
                 "interval (0 = as fast as the program takes them)")
      ->check(CLI::NonNegativeNumber);
  AddPipelineOptions(&cli, &p);
  cli.add_option("--telemetry", config.telemetry,
                 "Where the vehicle was for each frame, instead of EXIF GPS: mavlink-udp:HOST:PORT (listen, e.g. "
                 "0.0.0.0:14550), mavlink-serial:DEVICE:BAUD (e.g. /dev/ttyAMA0:921600), tlog:FILE (a MAVLink "
                 "telemetry log of the replayed flight), geo:FILE (OpenDroneMap geo.txt); timing keys: telemetry.* in "
                 "--config");
  bool no_live_tiles = false;
  AddLiveViewOptions(&cli, &config, &no_live_tiles);
  cli.add_flag(
      "--no-products", [&](std::int64_t) { p.write_products = false; },
      "Do not write mosaic.kmz, tiles/ and index.html (mosaic.tif stays a COG)");
  cli.add_option("--log-level", log_level, "trace|debug|info|warn|error");
  cli.add_flag("--print-config", print_config, "Print the effective configuration as YAML and exit");

  // The config file is applied first, then the command line again on top of it.
  try {
    cli.parse(argc, argv);
    if (!config_file.empty()) {
      std::string error;
      if (!app::LoadConfigFile(config_file, &config, &error)) {
        spdlog::error("{}", error);
        return app::kExitUsage;
      }
      cli.parse(argc, argv);
    }
  } catch (const CLI::ParseError& e) {
    return e.get_exit_code() == 0 ? cli.exit(e) : (cli.exit(e), app::kExitUsage);
  }
  spdlog::set_level(spdlog::level::from_str(log_level));
  // The live tiles are for the live server's clients: on with it, unless asked not to (or the config turned them on).
  if (!config.http.empty() && !no_live_tiles) p.live_tiles.enabled = true;
  if (no_live_tiles) p.live_tiles.enabled = false;
  if (list_cameras) return app::ListCameras();
  CountLogWarnings();  // report.json says how many warnings and errors the run logged
  std::string why;
  if (!p.Check(&why)) {
    spdlog::error("invalid configuration: {}", why);
    return app::kExitUsage;
  }
  if (print_config) {
    std::fputs(app::EffectiveConfigYaml(config).c_str(), stdout);
    return app::kExitOk;
  }
  if (!app::CheckLiveViewAccess(config, &why)) {  // before anything is opened or written
    spdlog::error("{}", why);
    return app::kExitUsage;
  }
  if (config.source.empty() || config.out_dir.empty()) {
    std::fprintf(stderr, "%s is required\nRun with --help for more information.\n",
                 config.source.empty() ? "--source" : "--out");
    return app::kExitUsage;
  }
  app::InstallStopHandlers();
  return app::Run(config);
}
