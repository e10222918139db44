#pragma once
// What the end-to-end tests read back from a session: report.json, and frames on the ground through the report's
// geotransform.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/geometry/transform.h"
#include "core/session/session_dir.h"

namespace uavm::test {

inline nlohmann::json ReadJson(const std::filesystem::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}

// Where report.json's GDAL geotransform `g` puts pixel `p` of a frame placed by mosaic_from_frame (pixel centres:
// GDAL's origin is the top-left pixel's corner).
inline Vec2 WorldOf(const nlohmann::json& g, const Mat3& mosaic_from_frame, const Vec2& p) {
  const Vec2 px = Apply(mosaic_from_frame, p) + Vec2(0.5, 0.5);
  return Vec2(g[0].get<double>() + px.x() * g[1].get<double>() + px.y() * g[2].get<double>(),
              g[3].get<double>() + px.x() * g[4].get<double>() + px.y() * g[5].get<double>());
}

inline Vec2 FrameCentre(cv::Size size) {
  return Vec2(0.5 * (size.width - 1), 0.5 * (size.height - 1));
}

inline Vec2 WorldOfCentre(const nlohmann::json& g, const Mat3& mosaic_from_frame, cv::Size size) {
  return WorldOf(g, mosaic_from_frame, FrameCentre(size));
}

// Frame centre and corners of each registered frame in the map's CRS (report.json's geotransform), by file name.
inline std::map<std::string, std::vector<Vec2>> FramesOnTheGround(const std::filesystem::path& session, cv::Size size) {
  const auto report = ReadJson(session / "report.json");
  const auto& g = report["georef"]["geotransform"];
  std::string text, err;
  std::vector<TransformRow> rows;
  EXPECT_TRUE(ReadTextFile((session / "transforms.csv").string(), &text, &err)) << err;
  EXPECT_TRUE(ParseTransformsCsv(text, &rows, &err)) << err;
  std::map<std::string, std::vector<Vec2>> out;
  for (const auto& r : rows) {
    if (!r.registered) continue;
    std::vector<Vec2> points{FrameCentre(size)};
    for (const auto& c : ImageCorners(size.width, size.height)) points.push_back(c);
    for (auto& p : points) p = WorldOf(g, r.mosaic_from_frame, p);
    out[r.filename] = points;
  }
  return out;
}

}  // namespace uavm::test
