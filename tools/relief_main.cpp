// uavmosaic-relief: a survey flown over a synthetic scene with relief and known truth (tools/relief_flight.h), and the
// ground tool's products measured against that truth.
//   uavmosaic-relief fly --out DIR [options]
//   uavmosaic-relief compare DIR --ortho ortho.tif [--dsm dsm.tif --dsm-filled dsm_filled.tif] [--dtm dtm.tif]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>

#include "tools/relief_flight.h"

int main(int argc, char** argv) {
  CLI::App app{"Synthetic survey over relief (buildings, trees, a slope) with its truth, and products against it"};
  app.require_subcommand(1);
  uavm::tools::ReliefFlightOptions o;
  std::string out;
  CLI::App* fly = app.add_subcommand("fly", "render the flight: images/, geo.txt, geo_truth.txt, truth/");
  fly->add_option("--out", out, "output folder")->required();
  fly->add_option("--seed", o.seed, "scene and noise seed");
  fly->add_option("--half-extent", o.half_extent_m, "the scene is [-H, H]^2 metres");
  fly->add_option("--buildings", o.buildings, "buildings (8-25 m)");
  fly->add_option("--trees", o.trees, "trees (6-14 m)");
  fly->add_option("--width", o.width, "frame width, px");
  fly->add_option("--height", o.height, "frame height, px");
  fly->add_option("--hfov", o.hfov_deg, "horizontal field of view, degrees");
  fly->add_option("--altitude", o.altitude_m, "flight height above the ground at the origin, m");
  fly->add_option("--forward-overlap", o.forward_overlap, "forward overlap");
  fly->add_option("--side-overlap", o.side_overlap, "side overlap");
  fly->add_option("--gps-sigma", o.gps_sigma_m, "reported positions' horizontal noise per axis, m");
  fly->add_option("--gps-vertical-sigma", o.gps_vertical_sigma_m, "reported positions' vertical noise, m");
  fly->add_option("--tilt-sigma", o.tilt_sigma_deg, "camera pointing error about nadir, degrees");
  fly->add_option("--k1", o.k1, "lens radial k1");
  fly->add_option("--k2", o.k2, "lens radial k2");
  std::string flight_dir;
  uavm::tools::ProductPaths products;
  std::string report_path;
  CLI::App* compare = app.add_subcommand("compare", "measure products against DIR/truth (JSON on stdout)");
  compare->add_option("flight", flight_dir, "the folder `fly` wrote")->required();
  compare->add_option("--ortho", products.ortho, "orthophoto (ortho.tif, or the onboard mosaic.tif)");
  compare->add_option("--dsm", products.dsm, "DSM (dsm.tif)");
  compare->add_option("--dsm-filled", products.dsm_filled, "the DSM's fill mask (dsm_filled.tif)");
  compare->add_option("--dtm", products.dtm, "DTM (dtm.tif)");
  compare->add_option("--report", report_path, "also write the JSON here");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }
  std::string error;
  nlohmann::json js;
  if (fly->parsed()) {
    if (!uavm::tools::WriteReliefFlight(o, out, &js, &error)) {
      std::fprintf(stderr, "uavmosaic-relief: %s\n", error.c_str());
      return 4;
    }
  } else if (!uavm::tools::CompareWithTruth(flight_dir, products, &js, &error)) {
    std::fprintf(stderr, "uavmosaic-relief: %s\n", error.c_str());
    return 3;
  }
  std::printf("%s\n", js.dump(1).c_str());
  if (!report_path.empty()) std::ofstream(report_path) << js.dump(1) << '\n';
  return 0;
}
