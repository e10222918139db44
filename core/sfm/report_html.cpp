#include "core/sfm/report_html.h"

#include <cpl_string.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <vector>

#include "core/util/xml_escape.h"

namespace uavm::sfm {

namespace {

std::string Num(double v, int decimals) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(decimals);
  s << v;
  return s.str();
}

std::string Num(const nlohmann::json& v, int decimals) {
  return v.is_number() ? Num(v.get<double>(), decimals) : std::string("—");
}

// A picture as a data: URI (PNG; GDAL's base64, which the project already links).
std::string DataUri(const cv::Mat& image) {
  std::vector<uchar> png;
  if (image.empty() || !cv::imencode(".png", image, png, {cv::IMWRITE_PNG_COMPRESSION, 6})) return {};
  char* b64 = CPLBase64Encode(static_cast<int>(png.size()), png.data());
  std::string uri = std::string("data:image/png;base64,") + b64;
  CPLFree(b64);
  return uri;
}

// The long side of a picture shown in the report.
cv::Mat Fit(const cv::Mat& image, int long_side) {
  if (image.empty()) return image;
  const double k = std::min(1.0, static_cast<double>(long_side) / std::max(image.cols, image.rows));
  cv::Mat out;
  cv::resize(image, out, cv::Size(), k, k, k < 1.0 ? cv::INTER_AREA : cv::INTER_NEAREST);
  return out;
}

// Overlap counts as colours (0 transparent grey, 1 red ... 5+ green) with the counts' legend.
cv::Mat OverlapPicture(const cv::Mat& overlap, int long_side) {
  if (overlap.empty()) return {};
  cv::Mat bgr(overlap.size(), CV_8UC3, cv::Scalar(60, 60, 60));
  static const cv::Vec3b kColours[] = {{60, 60, 60},   {40, 40, 220},  {40, 140, 240},
                                       {40, 220, 240}, {80, 220, 150}, {60, 170, 60}};
  for (int r = 0; r < overlap.rows; ++r)
    for (int c = 0; c < overlap.cols; ++c)
      bgr.at<cv::Vec3b>(r, c) = kColours[std::min<int>(overlap.at<uchar>(r, c), 5)];
  const double k = static_cast<double>(long_side) / std::max(bgr.cols, bgr.rows);
  cv::Mat out;
  cv::resize(bgr, out, cv::Size(), k, k, cv::INTER_NEAREST);
  return out;
}

// The orthophoto with, in map coordinates through its geotransform, each camera's adjusted centre (dot), its GPS
// position's difference (a line, `scale` times its length) and each GCP's error vector.
std::string OrthoFigure(const nlohmann::json& js, const cv::Mat& ortho, std::string* note) {
  const cv::Mat shown = Fit(ortho, 1000);
  const std::string uri = DataUri(shown);
  if (uri.empty() || !js.contains("ortho") || !js["ortho"].contains("origin")) return {};
  const auto& o = js["ortho"];
  const double x0 = o["origin"][0].get<double>(), y0 = o["origin"][1].get<double>();
  const double gsd = o["gsd"].get<double>();
  const double k = static_cast<double>(shown.cols) / o["size"][0].get<double>();  // shown px per ortho px
  const auto at = [&](double x, double y) { return cv::Point2d((x - x0) / gsd * k, (y0 - y) / gsd * k); };
  // GPS differences are metres against a map hundreds of metres wide: drawn 10x (said in the caption).
  const double scale = 10.0;
  std::ostringstream svg;
  svg << "<svg viewBox='0 0 " << shown.cols << ' ' << shown.rows << "' width='" << shown.cols << "' height='"
      << shown.rows << "'><image href='" << uri << "' width='" << shown.cols << "' height='" << shown.rows << "'/>";
  int cameras = 0;
  for (const auto& im : js.value("images", nlohmann::json::array())) {
    const cv::Point2d c = at(im["centre"][0].get<double>(), im["centre"][1].get<double>());
    if (im.contains("gps")) {
      const cv::Point2d g = at(im["gps"][0].get<double>(), im["gps"][1].get<double>());
      const cv::Point2d tip = c + scale * (g - c);
      svg << "<line x1='" << Num(c.x, 1) << "' y1='" << Num(c.y, 1) << "' x2='" << Num(tip.x, 1) << "' y2='"
          << Num(tip.y, 1) << "' stroke='#ff0' stroke-width='1.5'/>";
    }
    svg << "<circle cx='" << Num(c.x, 1) << "' cy='" << Num(c.y, 1) << "' r='3' fill='#08f' stroke='#fff'/>";
    ++cameras;
  }
  // GCP error vectors, 100x (centimetres on the map).
  const double gcp_scale = 100.0;
  if (js.contains("gcp")) {
    const auto offset = js["coordinates"]["ply_and_colmap_offset_xy"];
    for (const auto& p : js["gcp"].value("points", nlohmann::json::array())) {
      if (!p.value("triangulated", false) || !p.contains("position_local")) continue;
      const double px = p["position_local"][0].get<double>() + offset[0].get<double>();
      const double py = p["position_local"][1].get<double>() + offset[1].get<double>();
      const cv::Point2d s = at(px, py);
      const cv::Point2d e =
          at(px + gcp_scale * p["error_m"][0].get<double>(), py + gcp_scale * p["error_m"][1].get<double>());
      const bool check = p["role"] == "checkpoint";
      const char* colour = check ? "#f0f" : "#f00";
      svg << "<line x1='" << Num(s.x, 1) << "' y1='" << Num(s.y, 1) << "' x2='" << Num(e.x, 1) << "' y2='"
          << Num(e.y, 1) << "' stroke='" << colour << "' stroke-width='2.5'/>"
          << "<rect x='" << Num(s.x - 5, 1) << "' y='" << Num(s.y - 5, 1) << "' width='10' height='10' fill='none' "
          << "stroke='" << colour << "' stroke-width='2'/><text x='" << Num(s.x + 8, 1) << "' y='" << Num(s.y - 8, 1)
          << "' fill='" << colour << "' font-size='13'>" << XmlEscape(p["name"].get<std::string>()) << "</text>";
    }
  }
  svg << "</svg>";
  *note = std::to_string(cameras) + " camera centres (blue); yellow: towards each frame's GPS position, drawn " +
          Num(scale, 0) + "x" +
          (js.contains("gcp") ? "; red (control) and magenta (checkpoints): each GCP's error, "
                                "drawn " +
                                    Num(gcp_scale, 0) + "x"
                              : std::string());
  return svg.str();
}

// Reprojection RMS per image as bars.
std::string ResidualChart(const nlohmann::json& images) {
  if (!images.is_array() || images.empty()) return {};
  double top = 0.0;
  for (const auto& im : images) top = std::max(top, im["rms_px"].get<double>());
  top = std::max(top, 0.1);
  const int bar = std::max(3, std::min(24, 900 / static_cast<int>(images.size())));
  const int height = 160, width = bar * static_cast<int>(images.size()) + 40;
  std::ostringstream svg;
  svg << "<svg width='" << width << "' height='" << height + 30 << "'><line x1='35' y1='" << height << "' x2='" << width
      << "' y2='" << height << "' stroke='#888'/>"
      << "<text x='0' y='12' font-size='11'>" << Num(top, 2) << " px</text>";
  int i = 0;
  for (const auto& im : images) {
    const double h = im["rms_px"].get<double>() / top * (height - 20);
    svg << "<rect x='" << 38 + i * bar << "' y='" << Num(height - h, 1) << "' width='" << bar - 1 << "' height='"
        << Num(h, 1) << "' fill='#4a8'><title>" << XmlEscape(im["name"].get<std::string>()) << ": "
        << Num(im["rms_px"], 3) << " px, " << im["observations"].get<size_t>() << " observations</title></rect>";
    ++i;
  }
  svg << "<text x='38' y='" << height + 20 << "' font-size='11'>images in flight order (hover: name, RMS, "
      << "observations)</text></svg>";
  return svg.str();
}

std::string Picture(const cv::Mat& image, int long_side, const std::string& alt) {
  const std::string uri = DataUri(Fit(image, long_side));
  return uri.empty() ? std::string("<p>(none)</p>") : "<img alt='" + alt + "' src='" + uri + "'/>";
}

}  // namespace

namespace {

// The flight's figures, its warnings and the frames left out.
void SummarySection(const nlohmann::json& js, std::ostringstream& h) {
  const size_t used = js.value("frames_used", size_t{0});
  const size_t left_out = js.value("frames_not_used", nlohmann::json::array()).size();
  h << "<h1>Ground reconstruction report</h1><table>"
    << "<tr><td>frames used / left out</td><td>" << used << " / " << left_out << "</td></tr>"
    << "<tr><td>map CRS</td><td>" << XmlEscape(js.value("crs", std::string("local"))) << "</td></tr>"
    << "<tr><td>ground sampling distance</td><td>" << Num(js.value("gsd_m", 0.0) * 100.0, 2) << " cm</td></tr>"
    << "<tr><td>sparse points / dense points</td><td>" << js.value("sparse_points", size_t{0}) << " / "
    << js.value("dense_points", size_t{0}) << "</td></tr>"
    << "<tr><td>bundle adjustment RMS</td><td>" << Num(js.value("ba_rms_before_px", 0.0), 3) << " &rarr; "
    << Num(js.value("ba_rms_after_px", 0.0), 3) << " px</td></tr>";
  if (js.contains("georef") && js["georef"].contains("rms_m"))
    h << "<tr><td>camera centres against GPS (RMS)</td><td>" << Num(js["georef"]["rms_m"], 3) << " m</td></tr>";
  if (js.contains("ortho"))
    h << "<tr><td>orthophoto</td><td>" << js["ortho"]["size"][0] << " &times; " << js["ortho"]["size"][1] << " px, "
      << js["ortho"]["images_used"] << " frames</td></tr>";
  h << "<tr><td>DSM measured / filled</td><td>" << Num(100.0 * js.value("dsm_measured_fraction", 0.0), 1) << " % / "
    << Num(100.0 * js.value("dsm_filled_fraction", 0.0), 1) << " %</td></tr></table>";
  for (const auto& w : js.value("warnings", nlohmann::json::array()))
    h << "<p class='warn'>warning: " << XmlEscape(w.get<std::string>()) << "</p>";
  for (const auto& f : js.value("frames_not_used", nlohmann::json::array()))
    h << "<p class='warn'>left out: " << XmlEscape(f.dump()) << "</p>";
}

void CamerasSection(const nlohmann::json& js, std::ostringstream& h) {
  h << "<h2>Cameras</h2><table><tr><th>camera</th><th>size</th><th>images</th><th>f px</th><th>cx</th><th>cy</th>"
       "<th>k1</th><th>k2</th><th>p1</th><th>p2</th></tr>";
  int index = 0;
  for (const auto& c : js.value("cameras", nlohmann::json::array())) {
    h << "<tr><td>" << index++ << "</td><td>" << c.value("width", 0) << "&times;" << c.value("height", 0) << "</td><td>"
      << c.value("images", 0) << "</td><td>" << Num(c["fx"], 1) << "</td><td>" << Num(c["cx"], 1) << "</td><td>"
      << Num(c["cy"], 1) << "</td><td>" << Num(c.value("k1", nlohmann::json()), 4) << "</td><td>"
      << Num(c.value("k2", nlohmann::json()), 4) << "</td><td>" << Num(c.value("p1", nlohmann::json()), 5)
      << "</td><td>" << Num(c.value("p2", nlohmann::json()), 5) << "</td></tr>";
  }
  h << "</table>";
}

void ControlSection(const nlohmann::json& js, std::ostringstream& h) {
  if (js.contains("gcp")) {
    const auto& g = js["gcp"];
    h << "<h2>Ground control</h2><table><tr><th>point</th><th>role</th><th>clicks</th><th>dx m</th><th>dy m</th>"
         "<th>dz m</th><th>error GSD</th><th>click RMS px</th></tr>";
    for (const auto& p : g.value("points", nlohmann::json::array())) {
      h << "<tr><td>" << XmlEscape(p["name"].get<std::string>()) << "</td><td>" << p["role"].get<std::string>()
        << "</td><td>" << p["clicks"] << "</td>";
      if (p.value("triangulated", false))
        h << "<td>" << Num(p["error_m"][0], 3) << "</td><td>" << Num(p["error_m"][1], 3) << "</td><td>"
          << Num(p["error_m"][2], 3) << "</td><td>" << Num(p["error_gsd"], 2) << "</td><td>"
          << Num(p["click_rms_px"], 2) << "</td>";
      else
        h << "<td colspan='5'>not triangulated</td>";
      h << "</tr>";
    }
    h << "</table>";
    for (const char* key : {"control_rms", "checkpoint_rms"}) {
      if (g.contains(key) && g[key].is_object())
        h << "<p>" << key << ": " << Num(g[key]["total_m"], 3) << " m (" << Num(g[key]["total_gsd"], 2) << " GSD) over "
          << g[key]["points"] << " points</p>";
    }
  }
}

void TimingSection(const nlohmann::json& js, std::ostringstream& h) {
  h << "<h2>Time and memory per stage</h2><table><tr><th>stage</th><th>seconds</th><th>resident at its end, "
       "MiB</th><th>peak so far, MiB</th></tr>";
  const auto memory = js.value("stage_memory_mib", nlohmann::json::object());
  // In the order the stages run (a JSON object keeps its keys sorted); any other key after them.
  const auto timings = js.value("timings", nlohmann::json::object());
  std::vector<std::string> keys = {"import_s",        "features_s",   "matching_s", "tracks_s",
                                   "initial_poses_s", "bundle_s",     "georef_s",   "gcp_s",
                                   "dense_s",         "fusion_dsm_s", "ortho_s",    "write_s"};
  for (const auto& item : timings.items())
    if (std::find(keys.begin(), keys.end(), item.key()) == keys.end() && item.key() != "total_s")
      keys.push_back(item.key());
  keys.emplace_back("total_s");
  for (const auto& key : keys) {
    if (!timings.contains(key)) continue;
    const auto& seconds = timings[key];
    std::string stage = key;
    if (stage.size() > 2 && stage.substr(stage.size() - 2) == "_s") stage.resize(stage.size() - 2);
    h << "<tr><td>" << XmlEscape(stage) << "</td><td>" << Num(seconds, 2) << "</td>";
    if (memory.contains(key))
      h << "<td>" << Num(memory[key]["rss_end"], 0) << "</td><td>" << Num(memory[key]["peak_so_far"], 0) << "</td>";
    else
      h << "<td>—</td><td>—</td>";
    h << "</tr>";
  }
  h << "</table><p class='note'>A stage whose &lsquo;peak so far&rsquo; is above the stage before it set the run's "
       "peak there.</p></body></html>\n";
}

}  // namespace

bool WriteReportHtml(const std::string& path, const nlohmann::json& js, const ReportPictures& pictures,
                     std::string* error) {
  std::ostringstream h;
  h << "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>uavmosaic ground report</title><style>"
       "body{font-family:sans-serif;margin:24px;max-width:1100px;color:#222}h1{font-size:22px}h2{font-size:17px;"
       "margin-top:28px;border-bottom:1px solid #ccc}table{border-collapse:collapse;font-size:13px}td,th{border:1px "
       "solid #ccc;padding:3px 7px;text-align:right}th{background:#eee}td:first-child{text-align:left}"
       ".note{font-size:12px;color:#555}.warn{color:#a40}img{max-width:100%}.row{display:flex;gap:16px}"
       "</style></head><body>";
  SummarySection(js, h);
  std::string note;
  const std::string figure = OrthoFigure(js, pictures.ortho, &note);
  if (!figure.empty())
    h << "<h2>Orthophoto, cameras and control</h2>" << figure << "<p class='note'>" << note << "</p>";
  if (!pictures.overlap.empty())
    h << "<h2>Overlap</h2>" << Picture(OverlapPicture(pictures.overlap, 600), 600, "overlap")
      << "<p class='note'>frames that see the ground unoccluded: grey 0, red 1, orange 2, yellow 3, light green 4, "
         "green 5 or more</p>";

  CamerasSection(js, h);
  h << "<h2>Reprojection residuals per image</h2>" << ResidualChart(js.value("images", nlohmann::json::array()));

  ControlSection(js, h);
  h << "<h2>Surface and terrain</h2><div class='row'><div><p>DSM</p>" << Picture(pictures.dsm, 520, "DSM")
    << "</div><div><p>DTM (ground under buildings and trees)</p>" << Picture(pictures.dtm, 520, "DTM")
    << "</div></div>";

  TimingSection(js, h);
  std::ofstream out(path);
  out << h.str();
  out.close();
  if (!out) {
    *error = "cannot write " + path;
    return false;
  }
  return true;
}

}  // namespace uavm::sfm
