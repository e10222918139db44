// report.html (core/sfm/report_html.h) from a summary: self-contained, every section, what it draws on the orthophoto
// where the summary puts it, names escaped.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/sfm/report_html.h"

namespace uavm::sfm {
namespace {

namespace fs = std::filesystem;

size_t Count(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + what.size())) ++n;
  return n;
}

nlohmann::json Summary() {
  nlohmann::json js = {
      {"frames_used", 3},
      {"frames_not_used", nlohmann::json::array({{{"file", "bad.jpg"}, {"reason", "cannot read"}}})},
      {"crs", "EPSG:32615"},
      {"gsd_m", 0.05},
      {"sparse_points", 1000},
      {"dense_points", 50000},
      {"ba_rms_before_px", 2.0},
      {"ba_rms_after_px", 0.4},
      {"warnings", {"dense <matching> & more"}},
      {"coordinates", {{"ply_and_colmap_offset_xy", {500000.0, 4000000.0}}}},
      {"ortho", {{"size", {200, 100}}, {"gsd", 0.5}, {"images_used", 3}, {"origin", {500000.0, 4000050.0}}}},
      {"cameras",
       {{{"width", 4000},
         {"height", 3000},
         {"images", 3},
         {"fx", 3000.0},
         {"cx", 2000.0},
         {"cy", 1500.0},
         {"k1", 0.01},
         {"k2", 0.0},
         {"p1", 0.0},
         {"p2", 0.0}}}},
      {"timings", {{"bundle_s", 2.0}, {"import_s", 0.1}, {"total_s", 3.0}}},
      {"stage_memory_mib", {{"bundle_s", {{"rss_end", 300.0}, {"peak_so_far", 400.0}}}}}};
  for (int i = 0; i < 3; ++i)
    js["images"].push_back({{"name", "img" + std::to_string(i) + ".jpg"},
                            {"centre", {500010.0 + 30 * i, 4000025.0, 100.0}},
                            {"gps", {500011.0 + 30 * i, 4000025.0, 101.0}},
                            {"observations", 100 + i},
                            {"rms_px", 0.3 + 0.1 * i}});
  js["gcp"] = {{"points",
                {{{"name", "g<1>"},
                  {"role", "control"},
                  {"clicks", 4},
                  {"triangulated", true},
                  {"position_local", {50.0, 25.0, 3.0}},
                  {"error_m", {0.01, -0.02, 0.03}},
                  {"error_gsd", 0.5},
                  {"click_rms_px", 0.4}},
                 {{"name", "c1"},
                  {"role", "checkpoint"},
                  {"clicks", 1},
                  {"triangulated", false},
                  {"position_local", {10.0, 10.0, 3.0}}}}},
               {"checkpoint_rms", nullptr}};
  return js;
}

TEST(ReportHtml, SelfContainedWithEverySectionAndItsFigures) {
  const fs::path path = fs::temp_directory_path() / ("uavm_report_" + std::to_string(::getpid()) + ".html");
  ReportPictures pictures;
  pictures.ortho = cv::Mat(50, 100, CV_8UC4, cv::Scalar(40, 120, 60, 255));
  pictures.overlap = cv::Mat(7, 13, CV_8U, cv::Scalar(3));
  pictures.dsm = cv::Mat(40, 40, CV_8UC3, cv::Scalar(10, 20, 30));
  std::string error;
  ASSERT_TRUE(WriteReportHtml(path.string(), Summary(), pictures, &error)) << error;
  std::stringstream text;
  text << std::ifstream(path).rdbuf();
  const std::string html = text.str();
  fs::remove(path);
  for (const char* section : {"Orthophoto, cameras and control", "Overlap", "Cameras", "Reprojection residuals",
                              "Ground control", "Surface and terrain", "Time and memory per stage"})
    EXPECT_NE(html.find(section), std::string::npos) << section;
  EXPECT_EQ(Count(html, "data:image/png;base64,"), 3u);  // ortho, overlap, DSM; no DTM given: "(none)"
  EXPECT_NE(html.find("(none)"), std::string::npos);
  EXPECT_EQ(html.find("http"), std::string::npos);  // nothing fetched, no link out
  // One dot per camera; the control point's error drawn, the untriangulated checkpoint not.
  EXPECT_EQ(Count(html, "<circle"), 3u);
  EXPECT_EQ(Count(html, "<rect x='"), 1u + 3u);  // the GCP's marker and the three residual bars
  // The first camera at (500010, 4000025) is (10, 25) m from the origin: 20, 50 ortho px, halved on the 100 px picture.
  EXPECT_NE(html.find("<circle cx='10.0' cy='25.0'"), std::string::npos);
  // Names escaped, warnings and left-out frames said, stages in running order.
  EXPECT_NE(html.find("g&lt;1&gt;"), std::string::npos);
  EXPECT_EQ(html.find("g<1>"), std::string::npos);
  EXPECT_NE(html.find("dense &lt;matching&gt; &amp; more"), std::string::npos);
  EXPECT_NE(html.find("bad.jpg"), std::string::npos);
  EXPECT_LT(html.find(">import<"), html.find(">bundle<"));
  EXPECT_LT(html.find(">bundle<"), html.find(">total<"));
}

}  // namespace
}  // namespace uavm::sfm
