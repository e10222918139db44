#pragma once
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <unordered_set>
#include <vector>

#include "core/georef/georef.h"
#include "core/georef/telemetry_bridge.h"
#include "core/pipeline/flight_record.h"
#include "core/pipeline/options.h"

namespace uavm {

// Where each frame of the map goes on the canvas at the end of the flight: the solved component placed at
// mosaic_scale (the median frame's resolution), georeferenced from the frames' GPS and turned north-up, then the
// frames and pieces no image links placed by telemetry (bridging) and the canvas grown to hold them.
class CanvasPlacement {
 public:
  // Borrows `record` and `solution`, which must outlive the placement.
  CanvasPlacement(const PipelineOptions& options, const FlightRecord* record, const Solution* solution);
  void Place();

  // The map's frames (the component, then the bridged ones), each frame's canvas_from_original (identity for the
  // others), the canvas and its pixels per reference-frame pixel.
  [[nodiscard]] const std::vector<int>& placed() const { return placed_; }
  [[nodiscard]] const std::vector<Mat3>& canvas_from_original() const { return canvas_from_original_; }
  [[nodiscard]] cv::Size canvas() const { return canvas_; }
  [[nodiscard]] double scale() const { return scale_; }
  [[nodiscard]] const GeorefFit& georef() const { return georef_; }
  [[nodiscard]] const std::unordered_set<int>& placed_by_telemetry() const { return placed_by_telemetry_; }
  // report.json "georef" and "bridge".
  [[nodiscard]] nlohmann::json GeorefJson() const;
  [[nodiscard]] const nlohmann::json& bridge_report() const { return bridge_report_; }

 private:
  [[nodiscard]] double PlaceComponent(const std::vector<int>& component);
  [[nodiscard]] GeorefFit GeorefCanvas(const std::vector<int>& component,
                                       const std::function<void(const Mat3&)>& place);
  void BridgeFrames();
  [[nodiscard]] std::vector<BridgeFrame> BridgeInputs(int* candidates) const;
  [[nodiscard]] bool GrowCanvas(const std::vector<int>& placed);
  [[nodiscard]] static nlohmann::json BridgeJson(const BridgeResult& r, int candidates);

  const PipelineOptions& options_;  // borrowed
  const FlightRecord* record_;      // borrowed
  const Solution* solution_;        // borrowed
  std::vector<int> placed_;
  std::vector<Mat3> canvas_from_original_;
  cv::Size canvas_{0, 0};
  double scale_ = 0.0;
  GeorefFit georef_;
  double rotation_removed_deg_ = 0;
  int gps_frames_ = 0;
  std::unordered_set<int> placed_by_telemetry_;
  nlohmann::json bridge_report_ = nlohmann::json::object();
};

}  // namespace uavm
