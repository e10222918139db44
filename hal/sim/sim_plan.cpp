#include "hal/sim/sim_plan.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <variant>

#include "core/util/fail.h"
#include "core/util/portable_random.h"

namespace uavm::hal {

namespace {

constexpr double kPi = 3.14159265358979323846;
double Rad(double deg) {
  return deg * kPi / 180.0;
}

using FieldPtr = std::variant<int*, double*, uint64_t*, std::string*>;

std::map<std::string, FieldPtr> Fields(SimPlan& p) {
  return {{"canvas", &p.canvas},
          {"frame_width", &p.frame_width},
          {"frame_height", &p.frame_height},
          {"focal_px", &p.focal_px},
          {"gsd", &p.gsd},
          {"strips", &p.strips},
          {"strip_length", &p.strip_length},
          {"strip_spacing", &p.strip_spacing},
          {"forward_overlap", &p.forward_overlap},
          {"side_overlap", &p.side_overlap},
          {"yaw_jitter_deg", &p.yaw_jitter_deg},
          {"altitude_change", &p.altitude_change},
          {"altitude_drift", &p.altitude_drift},
          {"tilt_deg", &p.tilt_deg},
          {"exposure_gain", &p.exposure_gain},
          {"exposure_offset", &p.exposure_offset},
          {"white_balance", &p.white_balance},
          {"vignetting", &p.vignetting},
          {"vignetting_per_channel", &p.vignetting_per_channel},
          {"shading_offset_x", &p.shading_offset_x},
          {"shading_offset_y", &p.shading_offset_y},
          {"hotspot", &p.hotspot},
          {"hotspot_width_deg", &p.hotspot_width_deg},
          {"sun_elevation_deg", &p.sun_elevation_deg},
          {"sun_azimuth_deg", &p.sun_azimuth_deg},
          {"shadow", &p.shadow},
          {"shadow_radius_px", &p.shadow_radius_px},
          {"k1", &p.k1},
          {"k2", &p.k2},
          {"p1", &p.p1},
          {"p2", &p.p2},
          {"noise_sigma", &p.noise_sigma},
          {"blur_px", &p.blur_px},
          {"jpeg_quality", &p.jpeg_quality},
          {"passes", &p.passes},
          {"pass_shift", &p.pass_shift},
          {"margin", &p.margin},
          {"seed", &p.seed},
          {"gps", &p.gps},
          {"origin_lat", &p.origin_lat},
          {"origin_lon", &p.origin_lon},
          {"metres_per_px", &p.metres_per_px},
          {"flight_altitude_m", &p.flight_altitude_m},
          {"gps_noise_m", &p.gps_noise_m},
          {"gps_bias_m", &p.gps_bias_m},
          {"heading_noise_deg", &p.heading_noise_deg},
          {"water_from", &p.water_from},
          {"water_to", &p.water_to},
          {"frame_interval_s", &p.frame_interval_s},
          {"telemetry_hz", &p.telemetry_hz},
          {"attitude_noise_deg", &p.attitude_noise_deg},
          {"camera_latency_ms", &p.camera_latency_ms},
          {"telemetry_lost_from", &p.telemetry_lost_from},
          {"telemetry_lost_to", &p.telemetry_lost_to},
          {"gps_no_fix_from", &p.gps_no_fix_from},
          {"gps_no_fix_to", &p.gps_no_fix_to},
          {"live_camera", &p.live_camera},
          {"start_unix_s", &p.start_unix_s},
          {"mavlink_udp", &p.mavlink_udp},
          {"mavlink_signing_key_file", &p.mavlink_signing_key_file}};
}

using Draws = PortableRandom;  // the flight must not change with the machine that makes it

}  // namespace

bool SimPlan::Check(std::string* error) const {
  if (frame_width < 16 || frame_height < 16) return Fail(error, "frame_width and frame_height must be >= 16");
  if (focal_px < 0) return Fail(error, "focal_px must be >= 0");
  if (gps != 0 && gps != 1) return Fail(error, "gps must be 0 or 1");
  if (!(std::abs(origin_lat) < 84 && std::abs(origin_lon) <= 180)) return Fail(error, "origin_lat/lon out of range");
  if (!(metres_per_px > 0) || !(gps_noise_m >= 0) || !(gps_bias_m >= 0) || !(flight_altitude_m > 0))
    return Fail(error, "metres_per_px, flight_altitude_m must be > 0; gps_noise_m, gps_bias_m >= 0");
  if (!(heading_noise_deg >= 0)) return Fail(error, "heading_noise_deg must be >= 0");
  if (!(water_from >= 0 && water_to <= 1 && water_from <= water_to))
    return Fail(error, "water_from and water_to must satisfy 0 <= water_from <= water_to <= 1");
  if (!(gsd > 0)) return Fail(error, "gsd must be > 0");
  if (!CheckTelemetry(error) || !CheckCamera(error)) return false;
  if (strips < 0 || strip_length < 0 || strip_spacing < 0)
    return Fail(error, "strips/strip_length/spacing must be >= 0");
  if (forward_overlap < 0 || forward_overlap > 0.95) return Fail(error, "forward_overlap must be in [0, 0.95]");
  if (side_overlap < 0 || side_overlap > 0.95) return Fail(error, "side_overlap must be in [0, 0.95]");
  if (yaw_jitter_deg < 0) return Fail(error, "yaw_jitter_deg must be >= 0");
  if (std::abs(altitude_change) + std::abs(altitude_drift) > 0.8)
    return Fail(error, "|altitude_change| + |altitude_drift| must be <= 0.8");
  if (tilt_deg < 0 || tilt_deg > 30) return Fail(error, "tilt_deg must be in [0, 30]");
  if (exposure_gain < 0 || exposure_gain >= 1 || exposure_offset < 0)
    return Fail(error, "exposure_gain must be in [0, 1), exposure_offset >= 0");
  if (noise_sigma < 0 || blur_px < 0) return Fail(error, "noise_sigma and blur_px must be >= 0");
  if (jpeg_quality < 0 || jpeg_quality > 100) return Fail(error, "jpeg_quality must be in [0, 100]");
  if (passes < 1) return Fail(error, "passes must be >= 1");
  if (margin < 0) return Fail(error, "margin must be >= 0");
  return true;
}

bool SimPlan::CheckTelemetry(std::string* error) const {
  if (!(frame_interval_s > 0 && frame_interval_s <= 60)) return Fail(error, "frame_interval_s must be in (0, 60]");
  if (telemetry_hz < 1 || telemetry_hz > 50) return Fail(error, "telemetry_hz must be in [1, 50]");
  if (!(attitude_noise_deg >= 0)) return Fail(error, "attitude_noise_deg must be >= 0");
  if (!(camera_latency_ms >= 0 && camera_latency_ms < 1000 * frame_interval_s))
    return Fail(error, "camera_latency_ms must be in [0, frame_interval_s)");
  if (!mavlink_udp.empty() && gps != 1) return Fail(error, "mavlink_udp needs gps: 1");
  if (!mavlink_signing_key_file.empty() && gps != 1) return Fail(error, "mavlink_signing_key_file needs gps: 1");
  if (live_camera != 0 && live_camera != 1) return Fail(error, "live_camera must be 0 or 1");
  if (!(start_unix_s >= 0)) return Fail(error, "start_unix_s must be >= 0");
  if (!(telemetry_lost_from >= 0 && telemetry_lost_to <= 1 && telemetry_lost_from <= telemetry_lost_to))
    return Fail(error, "telemetry_lost_from and _to must satisfy 0 <= from <= to <= 1");
  if (!(gps_no_fix_from >= 0 && gps_no_fix_to <= 1 && gps_no_fix_from <= gps_no_fix_to))
    return Fail(error, "gps_no_fix_from and _to must satisfy 0 <= from <= to <= 1");
  return true;
}

bool SimPlan::CheckCamera(std::string* error) const {
  if (!(white_balance >= 0 && white_balance <= 0.5)) return Fail(error, "white_balance must be in [0, 0.5]");
  if (!(vignetting >= 0.2 && vignetting <= 1)) return Fail(error, "vignetting must be in [0.2, 1]");
  if (!(vignetting_per_channel >= 0 && vignetting * (1 + vignetting_per_channel) <= 1))
    return Fail(error, "vignetting_per_channel must be >= 0 with vignetting * (1 + vignetting_per_channel) <= 1");
  if (!(std::abs(shading_offset_x) <= 0.5 && std::abs(shading_offset_y) <= 0.5))
    return Fail(error, "shading_offset_x and _y must be within +-0.5 (of the half-diagonal)");
  if (!(hotspot >= 0 && hotspot <= 1 && hotspot_width_deg >= 0.5 && hotspot_width_deg <= 45))
    return Fail(error, "hotspot must be in [0, 1] and hotspot_width_deg in [0.5, 45]");
  if (!(sun_elevation_deg >= 10 && sun_elevation_deg <= 90 && std::isfinite(sun_azimuth_deg)))
    return Fail(error, "sun_elevation_deg must be in [10, 90] and sun_azimuth_deg finite");
  if (!(shadow >= 0 && shadow < 1 && shadow_radius_px >= 1 && shadow_radius_px <= 200))
    return Fail(error, "shadow must be in [0, 1) and shadow_radius_px in [1, 200]");
  if (!(std::isfinite(k1) && std::isfinite(k2) && std::isfinite(p1) && std::isfinite(p2)))
    return Fail(error, "k1, k2, p1, p2 must be finite");
  // Bound on the distortion's derivative over the frame: the rendering's undistortion converges and the lens maps
  // the frame one-to-one.
  const double r = 0.5 * std::hypot(frame_width, frame_height) / Focal();
  const double strength =
      3 * std::abs(k1) * r * r + 5 * std::abs(k2) * std::pow(r, 4) + 6 * (std::abs(p1) + std::abs(p2)) * r;
  if (!(strength <= 0.8))
    return Fail(error, "lens distortion too strong: 3|k1| R^2 + 5|k2| R^4 + 6(|p1| + |p2|) R = " +
                           std::to_string(strength) + " > 0.8 at the half-diagonal R = " + std::to_string(r));
  return true;
}

PinholeCamera SimPlan::Camera() const {
  return PinholeCamera::Centred(frame_width, frame_height, Focal(), {k1, k2, p1, p2});
}

RadialFalloff SimPlan::Vignetting(int channel) const {
  return RadialFalloff::FromCorner(vignetting * (1.0 + vignetting_per_channel * (channel - 1)));
}

bool ParseSimPlan(const std::string& yaml_text, const std::string& base_dir, SimPlan* plan, std::string* error) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const std::exception& e) {
    return Fail(error, std::string("sim plan: ") + e.what());
  }
  SimPlan p;
  if (!root.IsNull()) {
    if (!root.IsMap()) return Fail(error, "sim plan: top level must be a mapping");
    auto fields = Fields(p);
    for (const auto& kv : root) {
      const std::string key = kv.first.as<std::string>();
      const auto it = fields.find(key);
      if (it == fields.end()) {
        std::string known;
        for (const auto& f : fields) known += (known.empty() ? "" : ", ") + f.first;
        return Fail(error, "sim plan: unknown key '" + key + "' (known: " + known + ")");
      }
      try {
        std::visit([&](auto* ptr) { *ptr = kv.second.as<std::remove_pointer_t<decltype(ptr)>>(); }, it->second);
      } catch (const std::exception&) {
        return Fail(error, "sim plan: '" + key + "' has the wrong type");
      }
    }
  }
  if (!p.Check(error)) return Fail(error, "sim plan: " + *error);
  if (!p.canvas.empty() && !base_dir.empty() && std::filesystem::path(p.canvas).is_relative())
    p.canvas = (std::filesystem::path(base_dir) / p.canvas).string();
  if (!p.mavlink_signing_key_file.empty() && !base_dir.empty() &&
      std::filesystem::path(p.mavlink_signing_key_file).is_relative())
    p.mavlink_signing_key_file = (std::filesystem::path(base_dir) / p.mavlink_signing_key_file).string();
  *plan = p;
  return true;
}

bool LoadSimPlanFile(const std::string& path, SimPlan* plan, std::string* error) {
  std::ifstream in(path);
  if (!in) return Fail(error, "cannot read sim plan " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  if (!ParseSimPlan(ss.str(), std::filesystem::path(path).parent_path().string(), plan, error)) {
    *error = path + ": " + *error;
    return false;
  }
  return true;
}

std::string ToYaml(const SimPlan& plan) {
  SimPlan copy = plan;
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  for (const auto& [key, ptr] : Fields(copy)) {
    out << YAML::Key << key << YAML::Value;
    std::visit([&](auto* v) { out << *v; }, ptr);
  }
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

Mat3 CanvasFromFrame(const SimPlan& plan, const SimPose& pose) {
  const double f = plan.Focal();
  Mat3 k_inv = Mat3::Identity();
  k_inv(0, 0) = 1.0 / f;
  k_inv(1, 1) = 1.0 / f;
  k_inv(0, 2) = -(plan.frame_width - 1.0) / 2.0 / f;
  k_inv(1, 2) = -(plan.frame_height - 1.0) / 2.0 / f;
  const double cz = std::cos(Rad(pose.yaw_deg)), sz = std::sin(Rad(pose.yaw_deg));
  const double cr = std::cos(Rad(pose.roll_deg)), sr = std::sin(Rad(pose.roll_deg));
  const double cp = std::cos(Rad(pose.pitch_deg)), sp = std::sin(Rad(pose.pitch_deg));
  Mat3 rz, rx, ry;
  rz << cz, -sz, 0, sz, cz, 0, 0, 0, 1;
  rx << 1, 0, 0, 0, cr, -sr, 0, sr, cr;
  ry << cp, 0, sp, 0, 1, 0, -sp, 0, cp;
  // Ray d (world, z down) from the camera at height h hits the ground at position + h * d.xy / d.z.
  const double h = plan.gsd * f * pose.altitude;
  Mat3 ground;
  ground << h, 0, pose.position.x(), 0, h, pose.position.y(), 0, 0, 1;
  const Mat3 m = ground * rz * rx * ry * k_inv;
  return m / m(2, 2);
}

bool BuildFlight(const SimPlan& plan, cv::Size canvas_size, std::vector<SimPose>* poses, std::string* note,
                 std::string* error) {
  poses->clear();
  note->clear();
  const double w = plan.frame_width, ht = plan.frame_height, g = plan.gsd;
  const double fwd = std::max(w * g * (1.0 - plan.forward_overlap), 1.0);
  const double spacing =
      plan.strip_spacing > 0 ? plan.strip_spacing : std::max(ht * g * (1.0 - plan.side_overlap), 1.0);
  // Rough footprint extent, only to size the automatic strip length and count; the fit below is exact.
  const double amax = 1.0 + std::abs(plan.altitude_change) + std::abs(plan.altitude_drift);
  const double yaw3 = Rad(std::min(3.0 * plan.yaw_jitter_deg, 90.0));
  const double tilt_shift = 2.0 * plan.Focal() * g * amax * std::tan(Rad(plan.tilt_deg));
  const double bw = (w * std::cos(yaw3) + ht * std::sin(yaw3)) * g * amax * 1.05 + tilt_shift;
  const double bh = (w * std::sin(yaw3) + ht * std::cos(yaw3)) * g * amax * 1.05 + tilt_shift;
  const double usable_w = canvas_size.width - 1.0 - 2.0 * plan.margin;
  const double usable_h = canvas_size.height - 1.0 - 2.0 * plan.margin;
  const double length = plan.strip_length > 0 ? plan.strip_length : std::max(0.0, usable_w - bw);
  const int per_strip = static_cast<int>(std::floor(length / fwd + 1e-9)) + 1;
  const int strips =
      plan.strips > 0 ? plan.strips : std::max(1, static_cast<int>(std::floor((usable_h - bh) / spacing + 1e-9)) + 1);
  const int total = per_strip * strips * plan.passes;

  Draws draws(plan.seed);
  Draws white_balance_draws(plan.seed * 2654435761ULL + 12345);  // its own stream: see white_balance in sim_plan.h
  for (int pass = 0; pass < plan.passes; ++pass) {
    for (int s = 0; s < strips; ++s) {
      for (int k = 0; k < per_strip; ++k) {
        SimPose pose;
        pose.strip = s;
        pose.pass = pass;
        const bool back = s % 2 == 1;
        const double shift = pass * plan.pass_shift;
        pose.position = Vec2((back ? per_strip - 1 - k : k) * fwd + shift * fwd, s * spacing + shift * spacing);
        // Fixed draw order per frame, all drawn even when unused: one option never reshuffles another's draws.
        const double yaw_noise = draws.Normal();
        const double tilt_dir = draws.Uniform() * 2.0 * kPi;
        const double gain = draws.Symmetric();
        const double offset = draws.Symmetric();
        pose.yaw_deg = (back ? 180.0 : 0.0) + plan.yaw_jitter_deg * yaw_noise;
        pose.roll_deg = plan.tilt_deg * std::cos(tilt_dir);
        pose.pitch_deg = plan.tilt_deg * std::sin(tilt_dir);
        pose.gain = 1.0 + plan.exposure_gain * gain;
        pose.offset = plan.exposure_offset * offset;
        for (double& wb : pose.white_balance) wb = 1.0 + plan.white_balance * white_balance_draws.Symmetric();
        const double t = total > 1 ? static_cast<double>(poses->size()) / (total - 1) : 0.0;
        pose.altitude = 1.0 + plan.altitude_change * std::sin(2.0 * kPi * t) + plan.altitude_drift * t;
        poses->push_back(pose);
      }
    }
  }

  // Fit: footprints depend on the position only by a translation, so with relative footprint boxes [lo, hi] and
  // path offsets d from the pattern centre, scale s and centre c fit when margin <= c + s*d + lo and
  // c + s*d + hi <= size - 1 - margin for every frame. Take the largest s <= 1 (bisection) and the middle c.
  const size_t n = poses->size();
  std::vector<Vec2> lo(n), hi(n), d(n);
  Vec2 pmin(1e300, 1e300), pmax(-1e300, -1e300);
  for (const auto& p : *poses) {
    pmin = pmin.cwiseMin(p.position);
    pmax = pmax.cwiseMax(p.position);
  }
  const Vec2 pc = (pmin + pmax) / 2.0;
  for (size_t i = 0; i < n; ++i) {
    SimPose rel = (*poses)[i];
    rel.position = Vec2::Zero();
    const auto fp = Footprint(CanvasFromFrame(plan, rel), plan.frame_width, plan.frame_height);
    lo[i] = Vec2(1e300, 1e300);
    hi[i] = Vec2(-1e300, -1e300);
    for (const auto& q : fp) {
      lo[i] = lo[i].cwiseMin(Vec2(q.x, q.y));
      hi[i] = hi[i].cwiseMax(Vec2(q.x, q.y));
    }
    d[i] = (*poses)[i].position - pc;
  }
  const Vec2 size(canvas_size.width - 1.0, canvas_size.height - 1.0);
  auto place = [&](double s, Vec2* centre) {
    for (int a = 0; a < 2; ++a) {
      double low = -1e300, high = 1e300;
      for (size_t i = 0; i < n; ++i) {
        low = std::max(low, plan.margin - lo[i](a) - s * d[i](a));
        high = std::min(high, size(a) - plan.margin - hi[i](a) - s * d[i](a));
      }
      if (low > high) return false;
      (*centre)(a) = (low + high) / 2.0;
    }
    return true;
  };
  Vec2 centre;
  double scale = 1.0;
  if (!place(1.0, &centre)) {
    if (!place(0.0, &centre))
      return Fail(error, "sim: a frame footprint does not fit in the " + std::to_string(canvas_size.width) + "x" +
                             std::to_string(canvas_size.height) + " canvas (lower gsd or frame size)");
    double a = 0.0, b = 1.0;
    for (int it = 0; it < 50; ++it) {
      const double mid = (a + b) / 2.0;
      Vec2 c;
      (place(mid, &c) ? a : b) = mid;
    }
    scale = a;
    if (!place(scale, &centre)) return Fail(error, "sim: plan fit failed");
    std::ostringstream os;
    os << "sim plan shrunk to " << scale * 100.0 << "% to keep every footprint inside the canvas (frame spacing "
       << fwd * scale << " px, strip spacing " << spacing * scale << " px: overlaps are larger than planned)";
    *note = os.str();
  }
  for (size_t i = 0; i < n; ++i) (*poses)[i].position = centre + scale * d[i];
  return true;
}

LatLon CanvasToLatLon(const SimPlan& plan, cv::Size canvas, const Vec2& p) {
  constexpr double kEarthRadiusM = 6378137.0;
  const double east = (p.x() - 0.5 * (canvas.width - 1)) * plan.metres_per_px;
  const double north = -(p.y() - 0.5 * (canvas.height - 1)) * plan.metres_per_px;
  const double lat = plan.origin_lat + north / kEarthRadiusM * 180.0 / kPi;
  const double lon = plan.origin_lon + east / (kEarthRadiusM * std::cos(Rad(plan.origin_lat))) * 180.0 / kPi;
  return {lat, lon};
}

}  // namespace uavm::hal
