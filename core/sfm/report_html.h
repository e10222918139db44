#pragma once
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>

// The ground tool's accuracy report: report.html, one self-contained file (pictures as data: URIs, charts as inline
// SVG, no script, nothing fetched) that opens offline in any browser and can be mailed with the map.
namespace uavm::sfm {

struct ReportPictures {
  cv::Mat ortho;     // the orthophoto's quick-look (BGR or BGRA; empty = none)
  cv::Mat overlap;   // frames seeing each block of the orthophoto (OrthoReport::overlap; empty = none)
  cv::Mat dsm, dtm;  // previews (BGR; empty = none)
};

// Writes `path` from summary.json's figures: the flight and its cameras, the orthophoto with the camera positions
// against GPS and the GCP/checkpoint error vectors drawn on it, the overlap map, the reprojection residuals per image,
// the GCP/checkpoint table, the DSM and DTM previews, time (and memory) per stage, the warnings.
[[nodiscard]] bool WriteReportHtml(const std::string& path, const nlohmann::json& summary,
                                   const ReportPictures& pictures, std::string* error);

}  // namespace uavm::sfm
