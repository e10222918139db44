// Bridging by telemetry (core/georef/telemetry_bridge) on synthetic flights with known placements: a lawn-mower of
// frames placed by images (the reference), single frames and image-linked pieces that only telemetry can place.
#include "core/georef/telemetry_bridge.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace uavm {
namespace {

constexpr double kPi = 3.14159265358979323846;
const cv::Size kSize(400, 300);

// The true world_from_frame of an unmirrored nadir frame: centre at `c`, +x axis at `angle_deg` (from east towards
// north), `mpp` metres per pixel.
Mat3 Truth(const Vec2& c, double angle_deg, double mpp) {
  const double a = angle_deg * kPi / 180;
  Mat3 m = Mat3::Identity();
  m << mpp * std::cos(a), mpp * std::sin(a), 0, mpp * std::sin(a), -mpp * std::cos(a), 0, 0, 0, 1;
  const Vec2 centre(0.5 * (kSize.width - 1), 0.5 * (kSize.height - 1));
  m.topRightCorner<2, 1>() = c - m.topLeftCorner<2, 2>() * centre;
  return m;
}

struct Flight {
  std::vector<BridgeFrame> frames;
  std::vector<Mat3> truth;
};

// Two strips at ~80 m (0.02 m/px at 80 m), the first flown east, the second along `second_course_deg` (math angle;
// 180 = back west), the camera's +x 90 deg left of the direction of flight (a mounting offset), GPS noise `noise_m`,
// heading noise 2 deg, heading in the given sense (+1 clockwise compass). Frames in `bridged` are left to telemetry.
Flight MakeFlight(const std::vector<int>& bridged, double noise_m, bool with_heading, int sense = 1,
                  double second_course_deg = 180.0) {
  Flight f;
  std::mt19937 rng(7);
  std::normal_distribution<double> gps(0, noise_m), heading_noise(0, 2.0);
  const double second = second_course_deg * kPi / 180;
  for (int i = 0; i < 40; ++i) {
    const int strip = i / 20, k = i % 20;
    const Vec2 c = strip == 0 ? Vec2(500000 + 10.0 * k, 5000000)
                              : Vec2(500000 + 190, 5000060) + 10.0 * k * Vec2(std::cos(second), std::sin(second));
    const double course_deg = strip == 0 ? 0.0 : second_course_deg;
    const double height = 80.0 + 5.0 * std::sin(i * 0.3);
    const Mat3 truth = Truth(c, course_deg + 90.0, 0.02 * height / 80.0);
    BridgeFrame b;
    b.id = i;
    b.size = kSize;
    b.position = c + Vec2(gps(rng), gps(rng));
    b.height_m = height;
    if (with_heading) b.heading_deg = sense * (90.0 - course_deg) + heading_noise(rng);
    b.world_from_frame = truth;
    f.frames.push_back(b);
    f.truth.push_back(truth);
  }
  for (int id : bridged) f.frames[static_cast<size_t>(id)].piece = id;
  return f;
}

double CentreError(const Mat3& a, const Mat3& b) {
  const Vec2 c(0.5 * (kSize.width - 1), 0.5 * (kSize.height - 1));
  return (Apply(a, c) - Apply(b, c)).norm();
}

double CornerError(const Mat3& a, const Mat3& b) {
  double worst = 0;
  for (const auto& p : ImageCorners(kSize.width, kSize.height))
    worst = std::max(worst, (Apply(a, p) - Apply(b, p)).norm());
  return worst;
}

TEST(TelemetryBridgeTest, SingleFramesArePlacedWithinTheGpsNoiseAndTurnedByTheCalibratedHeading) {
  Flight f = MakeFlight({5, 6, 7, 30}, 1.0, true);
  const BridgeResult r = PlaceByTelemetry(f.frames, {});
  ASSERT_TRUE(r.calibrated) << r.failure;
  EXPECT_EQ(r.offset_from, "heading");
  EXPECT_EQ(r.rotation_from.at("heading"), 4);
  EXPECT_EQ(r.heading_sense, 1);
  EXPECT_LT(r.heading_rms_deg, 4.0);
  ASSERT_EQ(r.placed.size(), 4u);
  EXPECT_EQ(r.pieces_placed, 4);
  for (const auto& p : r.placed) {
    const Mat3& truth = f.truth[static_cast<size_t>(p.id)];
    EXPECT_LT(CentreError(p.world_from_frame, truth), 4.0) << "frame " << p.id;  // 1 m noise per axis
    // Corners: the centre error plus the rotation error (heading noise 2 deg over a 5 m half-diagonal).
    EXPECT_LT(CornerError(p.world_from_frame, truth), 5.0) << "frame " << p.id;
    const double det = p.world_from_frame.topLeftCorner<2, 2>().determinant();
    EXPECT_LT(det, 0) << "not mirrored like the others";
  }
}

TEST(TelemetryBridgeTest, HeadingInTheOtherSenseIsDetectedFromTheData) {
  // Back and forth fits either sense; a strip flown north tells them apart.
  Flight f = MakeFlight({12, 33}, 0.5, true, -1, 90.0);
  const BridgeResult r = PlaceByTelemetry(f.frames, {});
  ASSERT_TRUE(r.calibrated) << r.failure;
  EXPECT_EQ(r.heading_sense, -1);
  ASSERT_EQ(r.placed.size(), 2u);
  for (const auto& p : r.placed)
    EXPECT_LT(CornerError(p.world_from_frame, f.truth[static_cast<size_t>(p.id)]), 4.0) << "frame " << p.id;
}

TEST(TelemetryBridgeTest, WithoutHeadingTheDirectionOfTravelTurnsTheFrames) {
  // Frames 8 and 9 lie between image-placed frames of one strip: turned like them. Frames 18 and 19 end the first
  // strip: their image-placed neighbours (17, and 20 on the return strip) disagree, so the direction of travel turns
  // them; at 19 that direction cuts the corner of the turn (towards frame 20), so only its centre is sure.
  Flight f = MakeFlight({8, 9, 18, 19}, 0.5, false);
  const BridgeResult r = PlaceByTelemetry(f.frames, {});
  ASSERT_TRUE(r.calibrated) << r.failure;
  EXPECT_EQ(r.offset_from, "course");
  EXPECT_EQ(r.rotation_from.at("neighbours"), 2);
  EXPECT_EQ(r.rotation_from.at("course"), 2);
  ASSERT_EQ(r.placed.size(), 4u);
  for (const auto& p : r.placed) {
    const Mat3& truth = f.truth[static_cast<size_t>(p.id)];
    EXPECT_LT(CentreError(p.world_from_frame, truth), 2.0) << "frame " << p.id;
    if (p.id != 19) {
      EXPECT_LT(CornerError(p.world_from_frame, truth), 3.0) << "frame " << p.id;
    }
  }
}

TEST(TelemetryBridgeTest, AnImageLinkedPieceKeepsItsShapeAndIsPlacedAsAWhole) {
  // Frames 22..31 form a piece in coordinates of their own: a turned, scaled, y-down mosaic.
  Flight f = MakeFlight({}, 1.5, true);
  Mat3 piece_from_world = Mat3::Identity();
  const double a = 0.7, s = 30.0;
  piece_from_world << s * std::cos(a), -s * std::sin(a), 100, -s * std::sin(a), -s * std::cos(a), -40, 0, 0, 1;
  piece_from_world.topRightCorner<2, 1>() -= piece_from_world.topLeftCorner<2, 2>() * Vec2(500000, 5000000);
  for (int id = 22; id <= 31; ++id) {
    BridgeFrame& b = f.frames[static_cast<size_t>(id)];
    b.piece = 22;
    b.piece_from_frame = piece_from_world * f.truth[static_cast<size_t>(id)];
  }
  f.frames[25].position.reset();  // a member without a fix is still placed by its images
  const BridgeResult r = PlaceByTelemetry(f.frames, {});
  ASSERT_TRUE(r.calibrated) << r.failure;
  ASSERT_EQ(r.placed.size(), 10u);
  EXPECT_EQ(r.pieces_placed, 1);
  double sum = 0;
  for (const auto& p : r.placed) {
    const double e = CentreError(p.world_from_frame, f.truth[static_cast<size_t>(p.id)]);
    sum += e * e;
    EXPECT_LT(CornerError(p.world_from_frame, f.truth[static_cast<size_t>(p.id)]), 4.0) << "frame " << p.id;
  }
  // Ten positions average the noise: the piece lands closer than one fix would.
  EXPECT_LT(std::sqrt(sum / 10), 1.5);
}

TEST(TelemetryBridgeTest, FramesWithoutPositionOrCalibrationAreNotPlaced) {
  Flight f = MakeFlight({3, 4}, 1.0, true);
  f.frames[4].position.reset();
  BridgeResult r = PlaceByTelemetry(f.frames, {});
  ASSERT_EQ(r.placed.size(), 1u);
  EXPECT_EQ(r.placed[0].id, 3);
  EXPECT_EQ(r.frames_without_position, 1);

  // No reference frame carries a position: nothing to calibrate on, nothing placed, the reason said.
  for (auto& b : f.frames)
    if (b.piece < 0) b.position.reset();
  r = PlaceByTelemetry(f.frames, {});
  EXPECT_FALSE(r.calibrated);
  EXPECT_TRUE(r.placed.empty());
  EXPECT_NE(r.failure.find("too few"), std::string::npos) << r.failure;

  BridgeOptions off;
  off.enabled = false;
  EXPECT_TRUE(PlaceByTelemetry(MakeFlight({3}, 1.0, true).frames, off).placed.empty());
  std::string why;
  off.min_reference_frames = 1;
  EXPECT_FALSE(off.Check(&why));
}

}  // namespace
}  // namespace uavm
