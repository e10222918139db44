#include "tools/sim_writer.h"

#include <cmath>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "core/eval/ground_truth.h"
#include "core/session/session_dir.h"
#include "hal/sim/sim_telemetry.h"

namespace uavm::tools {

namespace fs = std::filesystem;

namespace {

eval::GtCamera CameraTruth(const hal::SimPlan& plan) {
  eval::GtCamera g;
  g.camera = plan.Camera();
  g.half_diagonal_px = 0.5 * std::hypot(plan.frame_width, plan.frame_height);  // as SimSource renders
  for (int c = 0; c < 3; ++c) g.vignetting[static_cast<size_t>(c)] = plan.Vignetting(c);
  return g;
}

}  // namespace

bool WriteSimFlight(hal::SimSource* source, const std::string& out_dir, int max_frames, std::string* error) {
  std::error_code ec;
  const fs::path root(out_dir);
  fs::create_directories(root / "images", ec);
  if (ec) {
    *error = "cannot create " + (root / "images").string() + ": " + ec.message();
    return false;
  }
  std::vector<eval::GtRow> rows;
  std::vector<eval::GtExposure> exposure;
  std::ostringstream geo;        // what the receiver reported (--telemetry geo:OUT/geo.txt)
  std::ostringstream geo_truth;  // where the frame centres really were, same format
  geo.precision(10);
  geo_truth.precision(10);
  geo << "EPSG:4326\n";
  geo_truth << "EPSG:4326\n";
  hal::Frame frame;
  while (max_frames <= 0 || static_cast<int>(rows.size()) < max_frames) {
    const hal::Status st = source->Next(&frame, error);
    if (st == hal::Status::kEndOfStream) break;
    if (st != hal::Status::kOk) return false;
    const fs::path file = root / "images" / frame.source_name;
    const auto& bytes = source->last_encoded();
    std::string contents;
    if (!bytes.empty()) {
      contents.assign(bytes.begin(), bytes.end());
    } else {
      std::vector<uchar> png;
      if (!cv::imencode(".png", frame.image, png)) {
        *error = "PNG encoding failed for " + frame.source_name;
        return false;
      }
      contents.assign(png.begin(), png.end());
    }
    if (!WriteFileAtomic(file.string(), contents, error)) return false;
    const hal::SimTruth& t = source->last_truth();
    rows.push_back({static_cast<int>(frame.index), frame.source_name, t.canvas_from_frame, t.affine});
    exposure.push_back(
        {static_cast<int>(frame.index), frame.source_name, t.pose.gain, t.pose.offset, t.pose.white_balance});
    // omega phi kappa: a nadir camera; kappa is the heading of the direction of flight (compass degrees).
    geo << frame.source_name << ' ' << t.gps_position.lon_deg << ' ' << t.gps_position.lat_deg << ' '
        << t.gps_altitude_m << " 0 0 " << t.gps_heading_deg << '\n';
    geo_truth << frame.source_name << ' ' << t.true_position.lon_deg << ' ' << t.true_position.lat_deg << ' '
              << t.gps_altitude_m << '\n';
  }
  if (rows.empty()) {
    *error = "the flight has no frames";
    return false;
  }
  hal::SimPlan plan = source->plan();
  plan.canvas = fs::absolute(plan.canvas, ec).string();
  const std::string yaml = "# effective plan of this simulated flight (uavmosaic-sim)\n" + hal::ToYaml(plan);
  const auto first = static_cast<size_t>(rows.front().index);
  const auto end = static_cast<size_t>(rows.back().index) + 1;
  if (plan.gps != 0 && !(WriteFileAtomic((root / "geo.txt").string(), geo.str(), error) &&
                         WriteFileAtomic((root / "geo_truth.txt").string(), geo_truth.str(), error) &&
                         WriteFileAtomic((root / "flight.tlog").string(), hal::SimTlog(*source, first, end), error)))
    return false;
  return WriteFileAtomic((root / "gt.csv").string(), eval::FormatGroundTruthCsv(rows), error) &&
         WriteFileAtomic((root / eval::kGroundTruthCameraFile).string(),
                         eval::FormatGroundTruthCamera(CameraTruth(plan)), error) &&
         WriteFileAtomic((root / eval::kGroundTruthExposureFile).string(), eval::FormatGroundTruthExposure(exposure),
                         error) &&
         WriteFileAtomic((root / "plan.yaml").string(), yaml, error);
}

}  // namespace uavm::tools
