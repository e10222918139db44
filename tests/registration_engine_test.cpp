// The registration engine on synthetic features with a known answer: a textured plane of points with distinct
// descriptors, frames as rotated windows onto it. No image, no process, no session: the engine alone, through the
// candidates, merges, relocalisation and solves a flight exercises.
#include "core/registration/registration_engine.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>
#include <stdexcept>

namespace uavm {
namespace {

constexpr int kWidth = 400;  // frame size, px
constexpr int kHeight = 300;

// Points on the ground plane, each with its own descriptor (what a frame sees of it is the same up to pixel noise).
struct World {
  std::vector<Vec2> points;
  cv::Mat descriptors;  // CV_32F, one row per point, 8-bit representable (what the session stores)

  World(int n, double width, double height, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> ux(0, width), uy(0, height);
    std::uniform_int_distribution<int> level(0, 255);
    cv::Mat q(n, 128, CV_8U);
    for (int i = 0; i < n; ++i) {
      points.emplace_back(ux(rng), uy(rng));
      for (int k = 0; k < 128; ++k) q.at<uchar>(i, k) = static_cast<uchar>(level(rng));
    }
    descriptors = DequantizeDescriptors(q);
  }
};

// world_from_frame of a frame centred at (cx, cy), turned by `deg`.
Mat3 Pose(double cx, double cy, double deg) {
  const double a = deg * M_PI / 180.0;
  Mat3 m = Mat3::Identity();
  m << std::cos(a), -std::sin(a), cx, std::sin(a), std::cos(a), cy, 0, 0, 1;
  return m * Translation(-0.5 * kWidth, -0.5 * kHeight);
}

Features Observe(const World& w, const Mat3& world_from_frame, std::mt19937* rng) {
  std::normal_distribution<double> noise(0.0, 0.2);
  const Mat3 frame_from_world = world_from_frame.inverse();
  Features f;
  std::vector<int> rows;
  for (size_t i = 0; i < w.points.size(); ++i) {
    const Vec2 p = Apply(frame_from_world, w.points[i]);
    if (p.x() < 0 || p.y() < 0 || p.x() > kWidth - 1 || p.y() > kHeight - 1) continue;
    f.points.emplace_back(static_cast<float>(p.x() + noise(*rng)), static_cast<float>(p.y() + noise(*rng)));
    rows.push_back(static_cast<int>(i));
  }
  f.descriptors.create(static_cast<int>(rows.size()), 128, CV_32F);
  for (size_t r = 0; r < rows.size(); ++r) w.descriptors.row(rows[r]).copyTo(f.descriptors.row(static_cast<int>(r)));
  return f;
}

class MapFeatures final : public FeatureProvider {
 public:
  std::shared_ptr<const Features> Get(int id) override {
    const auto it = features.find(id);
    return it == features.end() ? nullptr : it->second;
  }
  void ReleaseAll() override { released = true; }
  std::map<int, std::shared_ptr<const Features>> features;
  bool released = false;
};

// Keeps given-back points aside, as edges.bin does on disk.
class MemorySpill final : public EdgeSpill {
 public:
  bool Append(Edge* edge, std::string*) override {
    edge->stored_at = static_cast<int64_t>(stored_.size());
    stored_.push_back(*edge);
    return true;
  }
  bool Load(Edge* edge, std::string* error) override {
    if (edge->stored_at == flaky_at && flaky_loads++ % 2 == 1) {
      *error = "record unreadable (test)";
      return false;
    }
    const Edge& s = stored_.at(static_cast<size_t>(edge->stored_at));
    edge->points = s.points;
    edge->points_resident = true;
    ++loads;
    return true;
  }
  size_t Release(Edge* edge) override {
    if (keep_resident || !edge->points_resident || edge->stored_at < 0) return 0;
    const size_t bytes = edge->points.bytes();
    edge->points.Free();
    edge->points_resident = false;
    return bytes;
  }
  int loads = 0;
  bool keep_resident = false;  // stores, never gives back: every edge stays resident
  int64_t flaky_at = -1;       // the record whose every other load fails
  int flaky_loads = 0;

 private:
  std::vector<Edge> stored_;
};

// Runs a flight of `poses` through an engine and keeps what the test needs.
struct Flight {
  World world{12000, 3000, 1500, 7};
  std::vector<Mat3> poses;
  RegistrationOptions options;
  MapFeatures features;
  std::vector<FrameOutcome> outcomes;
  std::unique_ptr<RegistrationEngine> engine;
  std::map<int, PositionHint> hints;  // where telemetry places a frame

  Solution Run(EdgeSpill* spill = nullptr, int fail_id = -1) {
    engine = std::make_unique<RegistrationEngine>(options, &features, spill);
    std::mt19937 rng(11);
    for (size_t i = 0; i < poses.size(); ++i) {
      const int id = engine->AddFrame(cv::Size(kWidth, kHeight));
      if (id == fail_id) {
        engine->SetFailure(id, "could not be stored");
        outcomes.push_back(FrameOutcome::kFailed);
        continue;
      }
      auto f = std::make_shared<Features>(Observe(world, poses[i], &rng));
      features.features[id] = f;
      const auto hint = hints.find(id);
      outcomes.push_back(engine->Register(id, *f, nullptr, hint != hints.end() ? &hint->second : nullptr));
    }
    return engine->Finish();
  }

  // RMS error (px) of the component frames' corners against the truth, relative to the reference frame. With 0.2 px
  // of noise per point a chain of a dozen frames drifts by about a pixel (0.5-1.4 px here); a wrong edge or a bad
  // merge costs tens (neighbouring frames are 110 px apart).
  double CornerRms(const Solution& s) const {
    const Mat3 ref_from_world = poses.at(static_cast<size_t>(s.component.front())).inverse();
    double sum = 0;
    int n = 0;
    for (int id : s.component) {
      const Mat3 truth = ref_from_world * poses.at(static_cast<size_t>(id));
      for (const Vec2& c : {Vec2(0, 0), Vec2(kWidth - 1, 0), Vec2(0, kHeight - 1), Vec2(kWidth - 1, kHeight - 1)}) {
        sum += (Apply(engine->mosaic_from_work(id), c) - Apply(truth, c)).squaredNorm();
        ++n;
      }
    }
    return std::sqrt(sum / std::max(1, n));
  }

  [[nodiscard]] int EdgesBetweenDistantFrames(int min_gap) const {
    int n = 0;
    for (const Edge& e : engine->edges()) n += std::abs(e.src - e.tgt) >= min_gap ? 1 : 0;
    return n;
  }
};

TEST(RegistrationEngineTest, StripRegistersEveryFrameAtTheTruth) {
  Flight f;
  for (int i = 0; i < 12; ++i) f.poses.push_back(Pose(300 + 110.0 * i, 400, 2.0 * i));
  const Solution s = f.Run();
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(s.component.size(), 12u);
  EXPECT_EQ(s.component.front(), 0);
  for (FrameOutcome o : f.outcomes) EXPECT_EQ(o, FrameOutcome::kRegistered);
  // Every frame after the first two matched its K = 2 predecessors.
  EXPECT_GE(f.engine->edges().size(), 21u);
  EXPECT_LT(f.CornerRms(s), 2.0);
  EXPECT_LT(s.rms_px, 0.5);
  EXPECT_TRUE(f.features.released);  // Finish() let the feature memory go
}

TEST(RegistrationEngineTest, OverlapCandidatesCloseLoopsBetweenStrips) {
  Flight f;
  for (int i = 0; i < 8; ++i) f.poses.push_back(Pose(300 + 110.0 * i, 400, 0));
  for (int i = 7; i >= 0; --i) f.poses.push_back(Pose(300 + 110.0 * i, 580, 180));  // the way back, 60 % overlap
  const Solution s = f.Run();
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(s.component.size(), 16u);
  // Only overlap candidates link a frame to one flown much earlier (recent candidates are the last two).
  EXPECT_GE(f.EdgesBetweenDistantFrames(3), 6);
  EXPECT_LT(f.CornerRms(s), 2.0);
}

TEST(RegistrationEngineTest, LostFrameIsRelocalisedThroughTheGlobalIndex) {
  Flight f;
  for (int i = 0; i < 6; ++i) f.poses.push_back(Pose(300 + 110.0 * i, 400, 0));
  f.poses.push_back(Pose(2600, 1200, 30));  // new ground: nothing to match
  f.poses.push_back(Pose(400, 420, -10));   // back over frames 0-1, away from the last two
  const Solution s = f.Run();
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(f.outcomes[6], FrameOutcome::kNewComponent);
  EXPECT_EQ(f.outcomes[7], FrameOutcome::kRegistered);
  EXPECT_GE(f.engine->counters().relocalized, 1);
  EXPECT_EQ(s.component, (std::vector<int>{0, 1, 2, 3, 4, 5, 7}));
  EXPECT_EQ(f.engine->frame(6).failure, "no verified match with any candidate");
  EXPECT_LT(f.CornerRms(s), 2.0);
}

// Without the relocalisation index, a frame back over early ground after a jump is found only where telemetry
// places it: its centre ~20 px off (GPS noise), its heading unknown (the anchor's is used).
TEST(RegistrationEngineTest, TelemetryPositionFindsTheFramesAroundALostFrame) {
  const auto flight = [](Flight* f) {
    f->options.relocalization_candidates = 0;
    for (int i = 0; i < 6; ++i) f->poses.push_back(Pose(300 + 110.0 * i, 400, 0));
    f->poses.push_back(Pose(2600, 1200, 30));  // new ground: nothing to match
    f->poses.push_back(Pose(400, 420, 170));   // back over frames 0-1, flown the other way
  };
  Flight without;
  flight(&without);
  ASSERT_TRUE(without.Run().ok);
  EXPECT_EQ(without.outcomes[7], FrameOutcome::kNewComponent);

  Flight with;
  flight(&with);
  // Frame 0 anchors the mosaic at identity: the mosaic is frame 0's pixel grid.
  const Vec2 centre(0.5 * (kWidth - 1), 0.5 * (kHeight - 1));
  with.hints[7] = {0, Apply(with.poses[0].inverse() * with.poses[7], centre) + Vec2(15, -12)};
  with.hints[6] = {3, Vec2(5000, 5000)};  // a hint over no frame costs nothing and places nothing
  const Solution s = with.Run();
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(with.outcomes[6], FrameOutcome::kNewComponent);
  EXPECT_EQ(with.outcomes[7], FrameOutcome::kRegistered);
  EXPECT_EQ(with.engine->counters().joined_where_telemetry_placed, 1);
  EXPECT_EQ(with.engine->counters().relocalized, 0);
  EXPECT_EQ(s.component, (std::vector<int>{0, 1, 2, 3, 4, 5, 7}));
  EXPECT_LT(with.CornerRms(s), 2.0);
}

TEST(RegistrationEngineTest, PiecesOfTheFlightMergeWhenAFrameLinksThem) {
  Flight f;
  for (int i = 0; i < 5; ++i) f.poses.push_back(Pose(300 + 110.0 * i, 400, 0));
  // A second piece starts on ground of its own and flies back towards the first.
  for (int i = 0; i < 7; ++i) f.poses.push_back(Pose(1700 - 110.0 * i, 400, 5));
  const Solution s = f.Run();
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(f.outcomes[5], FrameOutcome::kNewComponent);
  EXPECT_GE(f.engine->counters().component_merges, 1);
  EXPECT_EQ(s.component.size(), 12u);
  EXPECT_LT(f.CornerRms(s), 2.0);
}

TEST(RegistrationEngineTest, WindowedSolvesSpillColdEdgesAndTheFinalSolveReadsThemBack) {
  Flight f;
  f.options.solve_window = 6;
  f.options.full_solve_every = 3;
  for (int i = 0; i < 24; ++i) f.poses.push_back(Pose(300 + 100.0 * (i % 12), 400 + 150.0 * (i / 12), 0));
  MemorySpill spill;
  const Solution s = f.Run(&spill);
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(s.component.size(), 24u);
  EXPECT_GT(f.engine->counters().edges_released, 0u);
  EXPECT_GT(spill.loads, 0);  // the final solve needed the given-back points
  for (const Edge& e : f.engine->edges()) EXPECT_TRUE(e.points_resident);
  EXPECT_LT(f.CornerRms(s), 2.0);
}

// Beyond end_correspondences the final solves read each given-back edge's share from the spill whenever they need it
// instead of holding all of them: the same solution as the same shares held in memory, to the last bit.
TEST(RegistrationEngineTest, AnEndBeyondItsCorrespondenceCapReadsEdgesBackAsTheSolvesNeedThem) {
  const auto fly = [](MemorySpill* spill) {
    auto f = std::make_unique<Flight>();
    f->options.solve_window = 6;
    f->options.full_solve_every = 3;
    f->options.end_correspondences = 300;  // a share of each edge's points (at least min_end_points)
    for (int i = 0; i < 24; ++i) f->poses.push_back(Pose(300 + 100.0 * (i % 12), 400 + 150.0 * (i / 12), 0));
    const Solution s = f->Run(spill);
    EXPECT_TRUE(s.ok) << s.failure;
    EXPECT_EQ(s.component.size(), 24u);
    EXPECT_GT(f->engine->counters().end_points_thinned, 0u);
    EXPECT_LT(f->CornerRms(s), 2.0);
    return f;
  };
  MemorySpill streamed;
  const auto a = fly(&streamed);
  MemorySpill resident;
  resident.keep_resident = true;
  const auto b = fly(&resident);
  const int released = static_cast<int>(a->engine->counters().edges_released);
  ASSERT_GT(released, 10);
  // The solves' passes each read the released edges again (a handful of passes), the resident run never reads.
  EXPECT_GT(streamed.loads, 4 * released);
  EXPECT_EQ(resident.loads, 0);
  for (int id = 0; id < 24; ++id)
    EXPECT_EQ(a->engine->mosaic_from_work(id), b->engine->mosaic_from_work(id)) << "frame " << id;
}

// An edge that reads back only every other time (a failing card) gives the end's passes different point counts: each
// pass takes it as it comes (no weight of another pass's points applied to it) and the flight is still solved.
TEST(RegistrationEngineTest, AnEdgeThatReadsBackOnlySometimesDoesNotUpsetTheEndSolves) {
  Flight f;
  f.options.solve_window = 6;
  f.options.full_solve_every = 3;
  f.options.end_correspondences = 300;
  for (int i = 0; i < 24; ++i) f.poses.push_back(Pose(300 + 100.0 * (i % 12), 400 + 150.0 * (i / 12), 0));
  MemorySpill spill;
  spill.flaky_at = 0;  // the flight's first edge: released early, read by every end pass
  const Solution s = f.Run(&spill);
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(s.component.size(), 24u);
  EXPECT_GT(spill.flaky_loads, 4);
  EXPECT_LT(f.CornerRms(s), 2.0);
}

TEST(RegistrationEngineTest, AFrameThatCouldNotBeStoredStaysOutWithItsReason) {
  Flight f;
  for (int i = 0; i < 6; ++i) f.poses.push_back(Pose(300 + 110.0 * i, 400, 0));
  const Solution s = f.Run(nullptr, /*fail_id=*/3);
  ASSERT_TRUE(s.ok) << s.failure;
  EXPECT_EQ(s.component, (std::vector<int>{0, 1, 2, 4, 5}));
  EXPECT_EQ(f.engine->frame(3).failure, "could not be stored");
  EXPECT_FALSE(f.engine->frame(3).has_features);
}

TEST(RegistrationEngineTest, RefusesBadOptionsAndMisuse) {
  MapFeatures features;
  RegistrationOptions bad;
  bad.recent_candidates = 0;
  EXPECT_THROW(RegistrationEngine(bad, &features, nullptr), std::invalid_argument);
  EXPECT_THROW(RegistrationEngine(RegistrationOptions{}, nullptr, nullptr), std::invalid_argument);
  RegistrationEngine engine(RegistrationOptions{}, &features, nullptr);
  const int first = engine.AddFrame(cv::Size(kWidth, kHeight));
  engine.AddFrame(cv::Size(kWidth, kHeight));
  EXPECT_THROW((void)engine.Register(first, Features{}), std::logic_error);  // only the newest frame registers
  EXPECT_THROW((void)engine.frame(5), std::out_of_range);
}

}  // namespace
}  // namespace uavm
