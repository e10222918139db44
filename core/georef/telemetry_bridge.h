#pragma once
#include <map>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// Bridging: frames (and pieces of the flight) that no image links to the map - water, a uniform field, blur - are
// placed from where the vehicle was: position, height above take-off and heading. The map placed by images is the
// reference: it calibrates how heading turns into the frame's rotation on the ground (the camera's mounting, and the
// sense of the heading), and how height turns into metres per pixel (the lens), so that no camera model is needed.
// World coordinates are those of the georeference (projected CRS: easting, northing in metres).
struct BridgeOptions {
  bool enabled = true;
  // Frames of the image-placed map with a position needed to calibrate scale and heading.
  int min_reference_frames = 3;
  // Calibration refused when the image-placed frames' rotations disagree with their headings by more than this
  // (circular RMS): the heading does not predict the rotation (e.g. a gimbal that turns on its own).
  double max_heading_rms_deg = 15.0;
  // A piece of several frames takes rotation and scale from its own GPS positions when they spread this far (its
  // images fix its shape; GPS noise then turns it by little); shorter pieces take them from heading and height.
  double piece_fit_min_spread_m = 40.0;

  [[nodiscard]] bool Check(std::string* why) const;
};

// One frame as bridging sees it. Pixels are original-resolution frame pixels.
struct BridgeFrame {
  int id = -1;
  cv::Size size;
  // -1: placed by images in the georeferenced map (world_from_frame set). Otherwise the piece it belongs to: frames
  // of one piece share the coordinates of piece_from_frame (an image-linked component the map could not join); a
  // frame linked to nothing is a piece of its own.
  int piece = -1;
  Mat3 world_from_frame = Mat3::Identity();
  Mat3 piece_from_frame = Mat3::Identity();
  std::optional<Vec2> position;       // world position of the ground under the frame centre
  std::optional<double> height_m;     // above take-off
  std::optional<double> altitude_m;   // above sea level, when the height above take-off is not known
  std::optional<double> heading_deg;  // compass, clockwise from north (the flight controller's yaw)
};

struct BridgePlacement {
  int id = -1;
  Mat3 world_from_frame = Mat3::Identity();
  int piece = -1;
};

// What bridging did (report.json "bridge").
struct BridgeResult {
  bool calibrated = false;
  std::string failure;  // why nothing was bridged, when !calibrated
  std::vector<BridgePlacement> placed;
  int pieces_placed = 0;
  int frames_without_position = 0;  // left out: nothing places them
  // Single frames by where their rotation came from: "heading", "neighbours" (the image-placed frames around it),
  // "course" (direction of travel between fixes), "nearest frame".
  std::map<std::string, int> rotation_from;
  std::string offset_from;        // what the offset below was calibrated on: "heading", "course" or "none"
  double heading_offset_deg = 0;  // image rotation minus the heading's direction, from the reference frames
  double heading_rms_deg = 0;
  int heading_sense = 1;               // +1 clockwise compass heading, -1 the other sense
  double metres_per_px_per_metre = 0;  // scale model: metres per pixel = this * height (0: unused)
  // Without heights above take-off, from altitudes above sea level: metres per pixel = this * (altitude - ground).
  double metres_per_px_per_metre_altitude = 0;
  double ground_altitude_m = 0;
  double metres_per_px = 0;  // the reference frames' median (when heights are missing)
  int reference_frames = 0;
};

// Places every frame with piece >= 0 that can be placed. Frames placed by images are never moved. Frames are taken
// in `frames` order as the order of flight (for the direction of travel).
[[nodiscard]] BridgeResult PlaceByTelemetry(const std::vector<BridgeFrame>& frames, const BridgeOptions& options);

}  // namespace uavm
