#pragma once
#include <array>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/geometry/camera_model.h"
#include "core/geometry/transform.h"

namespace uavm::hal {

// Flight plan and camera of a simulated flight, one flat YAML mapping. Unknown keys and wrong types are errors.
// Lengths are canvas pixels unless noted. Defaults in brackets.
//   canvas: image to fly over; relative paths are relative to the plan file [""; the caller may supply it]
//   frame_width, frame_height: frame size in pixels [400, 300]
//   focal_px: pinhole focal length in frame pixels, 0 = frame_width (about 53 deg horizontal field of view) [0]
//   gsd: canvas pixels per frame pixel at nominal altitude, nadir [1.5]
//   strips: number of lawn-mower strips along canvas +x, stacked along +y; 0 = as many as fit [0]
//   strip_length: distance flown by the frame centre along one strip; 0 = as long as fits [0]
//   strip_spacing: distance between strips; 0 = from side_overlap [0]
//   forward_overlap, side_overlap: fractions of the nominal footprint shared by neighbours; they set the frame
//     spacing (frame_width * gsd * (1 - forward_overlap)) and the default strip spacing [0.7, 0.3]
//   yaw_jitter_deg: sigma of a Gaussian yaw error. Yaw follows the flight: frame +x points along the flight,
//     return strips are turned 180 deg [0]
//   altitude_change: amplitude of a sinusoidal altitude change over the flight, fraction of nominal [0]
//   altitude_drift: linear altitude change from the first to the last frame, fraction of nominal [0]
//   tilt_deg: camera tilt off nadir (every frame, random direction): a perspective view of the flat canvas [0]
//   exposure_gain, exposure_offset: per-frame gain uniform in 1 +- gain, offset uniform in +- offset grey levels [0, 0]
//   white_balance: per-frame, per-channel gain uniform in 1 +- white_balance, on top of the exposure gain (drawn from
//     a generator of its own: the other draws of a flight do not change with it) [0]
//   vignetting: brightness of the image corners as a fraction of the centre, 0.2..1: every frame is multiplied by the
//     radial falloff V(r) = 1 + a1 r^2 + a2 r^4 with a1 = 1.25 (vignetting - 1), a2 = -0.25 (vignetting - 1), a
//     cos^4-like shape (RadialFalloff::FromCorner, core/geometry/camera_model.h); r = distance from the image centre
//     / half the image diagonal sqrt(w^2 + h^2) / 2, measured in the recorded (distorted) image [1 = none]
//   vignetting_per_channel: spread of the corner value between channels: B, G, R corners at vignetting x (1 - s, 1,
//     1 + s); vignetting x (1 + s) must stay <= 1 [0 = the same for B, G, R]
//   shading_offset_x, shading_offset_y: the vignetting's centre off the image centre, fractions of the half-diagonal
//     (an off-centre falloff, sensor shading): r is measured from there [0, 0]
//   hotspot: the opposition hotspot, brightness added around the antisolar point as a fraction (0.35: 35 % brighter at
//     its centre): H = 1 + hotspot exp(-g^2 / (2 w^2)), g the angle between a pixel's view ray and the antisolar
//     direction, w = hotspot_width_deg. The antisolar direction is fixed relative to the sun, not the lens: it lies
//     90 - sun_elevation_deg off nadir, towards sun_azimuth_deg + 180 on the canvas, so its place in the image turns
//     with the frame's yaw [0 = none]
//   hotspot_width_deg [8]; sun_elevation_deg [60]; sun_azimuth_deg: direction towards the sun on the canvas, degrees
//     from canvas +x towards +y (as yaw) [0]
//   shadow: the drone's own shadow at the antisolar point, the fraction of light it takes (0.5: half as bright), a disc
//     of shadow_radius_px frame pixels with a one-pixel soft edge [0 = none; radius 6]
//   A recorded pixel is gain x white_balance[c] x V_c(r) x H x S x canvas_c + offset (then noise, clipping, JPEG).
//   k1, k2, p1, p2: lens distortion, Brown-Conrady on normalised ideal coordinates x = (u - cx) / f, y = (v - cy) / f
//     (cx, cy the image centre, f = Focal()); see LensDistortion. The frame is the distorted picture: its pixel p
//     shows the canvas at canvas_from_frame(undistorted p), so the truth's homography acts on undistorted pixels.
//     k1 is not "the distortion at the corner": the radial displacement at the half-diagonal, as a fraction of that
//     radius, is k1 R^2 + k2 R^4 with R = sqrt(w^2 + h^2) / 2 / f (0.625 for 400x300 frames and the default focal,
//     so k1 = -0.1 moves the corners 3.9 % = 9.8 px inwards; the "-0.1 at the half-diagonal" is k1 = -0.256
//     there). 3 |k1| R^2 + 5 |k2| R^4 + 6 (|p1| + |p2|) R must be <= 0.8 (an invertible, moderate lens) [0, 0, 0, 0]
//   noise_sigma: Gaussian sensor noise, grey levels [0]
//   blur_px: motion blur length along the flight direction, frame pixels [0]
//   jpeg_quality: JPEG encode + decode round trip, 1..100; 0 = off [0]
//   passes: repeat the whole pattern this many times [1]
//   pass_shift: each repeat is shifted by this fraction of the frame and strip spacing [0.5]
//   margin: canvas pixels kept free around every footprint [2]
//   seed: every random draw derives from it; same seed, same frames [1]
//   gps: 1 = the flight carries GPS: each frame's metadata gets a noisy position of the ground under its centre (the
//     canvas is a map: +x east, +y south, its centre at origin_lat/lon, metres_per_px metres per canvas pixel) [0]
//   origin_lat, origin_lon: position of the canvas centre, degrees [46.8426, -91.9946]
//   metres_per_px: ground metres per canvas pixel [0.1]
//   flight_altitude_m: height above take-off at nominal altitude [80]
//   gps_noise_m: sigma of each fix's Gaussian error, per axis [1.5]; gps_bias_m: amplitude of a slowly turning
//     bias (one turn per 200 frames), as a receiver's error wanders [1.0]
//   heading_noise_deg: sigma of the Gaussian error of the heading that comes with each fix (compass degrees,
//     clockwise from north, of the direction of flight = frame +x) [2.0]
//   water_from, water_to: a band of calm water across the strips, canvas x from water_from to water_to as fractions
//     of the canvas width: featureless (a smooth gradient), so frames wholly over it match nothing [0, 0 = none]
//   With gps: 1 the flight controller's telemetry is simulated too (hal/sim/sim_telemetry.h): a .tlog beside the
//   frames (uavmosaic-sim) and, live, a MAVLink stream over UDP.
//   frame_interval_s: flight time between frames; frame i is taken at i * frame_interval_s [1.0]
//   telemetry_hz: rate of the position and attitude messages (HEARTBEAT and SYSTEM_TIME at 1 Hz) [10]
//   attitude_noise_deg: sigma of the Gaussian error of the reported roll and pitch [0.5]
//   camera_latency_ms: a live frame is delivered this long after it was taken, the telemetry going on meanwhile (the
//     mapper's telemetry.latency_ms compensates it) [0]
//   telemetry_lost_from, telemetry_lost_to: the link is lost over this part of the flight (fractions of the time from
//     the first frame to the last): no packet at all, camera triggers included [0, 0 = never]
//   gps_no_fix_from, gps_no_fix_to: the receiver has no fix over this part of the flight: GPS_RAW_INT without a fix,
//     GLOBAL_POSITION_INT and camera triggers at lat = lon = 0, as an autopilot without a position sends them [0, 0]
//   live_camera: 1 = `--source sim:PLAN` behaves as a companion computer's camera: frames come frame_interval_s
//     apart in real time and carry no GPS of their own (their position comes from --telemetry, e.g. gpsd) [0]
//   start_unix_s: live_camera's first frame is taken at this wall-clock time (UNIX seconds; it waits), so that another
//     program can play telemetry in step with the frames; 0 = at once [0]
//   mavlink_udp: "HOST:PORT": `--source sim:PLAN` sends the telemetry there over UDP in step with the frames, paced
//     in real time (frames frame_interval_s apart; a consumer that falls behind holds the flight's clock), and the
//     frames carry no GPS of their own (a companion computer's camera); "" = off [""]
//   mavlink_signing_key_file: the telemetry (live and .tlog) is MAVLink-2 signed with this key (a file as
//     telemetry.signing_key_file takes it; relative to the plan), link id 0; "" = unsigned [""]
// The plan is fitted inside the canvas: the pattern is centred, and shrunk (spacings scaled down, logged as a
// warning) when footprints would leave it.
struct SimPlan {
  std::string canvas;
  int frame_width = 400;
  int frame_height = 300;
  double focal_px = 0.0;
  double gsd = 1.5;
  int strips = 0;
  double strip_length = 0.0;
  double strip_spacing = 0.0;
  double forward_overlap = 0.7;
  double side_overlap = 0.3;
  double yaw_jitter_deg = 0.0;
  double altitude_change = 0.0;
  double altitude_drift = 0.0;
  double tilt_deg = 0.0;
  double exposure_gain = 0.0;
  double exposure_offset = 0.0;
  double white_balance = 0.0;
  double vignetting = 1.0;
  double vignetting_per_channel = 0.0;
  double shading_offset_x = 0.0;
  double shading_offset_y = 0.0;
  double hotspot = 0.0;
  double hotspot_width_deg = 8.0;
  double sun_elevation_deg = 60.0;
  double sun_azimuth_deg = 0.0;
  double shadow = 0.0;
  double shadow_radius_px = 6.0;
  double k1 = 0.0;
  double k2 = 0.0;
  double p1 = 0.0;
  double p2 = 0.0;
  double noise_sigma = 0.0;
  double blur_px = 0.0;
  int jpeg_quality = 0;
  int passes = 1;
  double pass_shift = 0.5;
  double margin = 2.0;
  uint64_t seed = 1;
  int gps = 0;
  double origin_lat = 46.8426;
  double origin_lon = -91.9946;
  double metres_per_px = 0.1;
  double flight_altitude_m = 80.0;
  double gps_noise_m = 1.5;
  double gps_bias_m = 1.0;
  double heading_noise_deg = 2.0;
  double water_from = 0.0;
  double water_to = 0.0;
  double frame_interval_s = 1.0;
  int telemetry_hz = 10;
  double attitude_noise_deg = 0.5;
  double camera_latency_ms = 0.0;
  double telemetry_lost_from = 0.0;
  double telemetry_lost_to = 0.0;
  double gps_no_fix_from = 0.0;
  double gps_no_fix_to = 0.0;
  int live_camera = 0;
  double start_unix_s = 0.0;
  std::string mavlink_udp;
  std::string mavlink_signing_key_file;

  [[nodiscard]] double Focal() const { return focal_px > 0 ? focal_px : frame_width; }
  // The frames' camera: principal point at the image centre, Focal(), the plan's k1, k2, p1, p2.
  [[nodiscard]] PinholeCamera Camera() const;
  // Vignetting of channel 0, 1, 2 = B, G, R (V(1) = vignetting x (1 - s, 1, 1 + s)).
  [[nodiscard]] RadialFalloff Vignetting(int channel) const;
  [[nodiscard]] bool Check(std::string* error) const;
  [[nodiscard]] bool CheckTelemetry(std::string* error) const;
  [[nodiscard]] bool CheckCamera(std::string* error) const;
};

// Parses YAML text; `base_dir` resolves a relative `canvas`. False with a message naming the key on any problem.
[[nodiscard]] bool ParseSimPlan(const std::string& yaml_text, const std::string& base_dir, SimPlan* plan,
                                std::string* error);
[[nodiscard]] bool LoadSimPlanFile(const std::string& path, SimPlan* plan, std::string* error);
// Every key with its value; ParseSimPlan reads it back to the same plan.
[[nodiscard]] std::string ToYaml(const SimPlan& plan);

// One simulated frame's pose and imaging parameters.
struct SimPose {
  int strip = 0;
  int pass = 0;
  Vec2 position = Vec2::Zero();  // canvas point under the camera centre
  double yaw_deg = 0.0;          // frame +x direction in the canvas, from canvas +x towards +y
  double altitude = 1.0;         // fraction of nominal
  double roll_deg = 0.0;         // rotation about the frame x axis
  double pitch_deg = 0.0;        // rotation about the frame y axis
  double gain = 1.0;
  double offset = 0.0;
  std::array<double, 3> white_balance{1.0, 1.0, 1.0};  // B, G, R gains on top of `gain`
};

// WGS84 position of canvas point `p` (local tangent plane at the canvas centre: exact enough over a few km).
struct LatLon {
  double lat_deg = 0, lon_deg = 0;
};
[[nodiscard]] LatLon CanvasToLatLon(const SimPlan& plan, cv::Size canvas, const Vec2& p);

// canvas_from_frame of a pinhole camera at `pose` looking down at the flat canvas (world z points into the ground,
// canvas x/y are world x/y). Normalised so that m(2, 2) = 1.
[[nodiscard]] Mat3 CanvasFromFrame(const SimPlan& plan, const SimPose& pose);

// Lays out the whole flight and fits it inside a canvas of `canvas_size`. `note` gets a one-line description of any
// shrinking (empty when none). False when even a single footprint cannot fit.
[[nodiscard]] bool BuildFlight(const SimPlan& plan, cv::Size canvas_size, std::vector<SimPose>* poses,
                               std::string* note, std::string* error);

}  // namespace uavm::hal
