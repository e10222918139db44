// The onboard session's units in-process, no program spawned: FlightSession (prepare, store, journal, register,
// resume) on a small flight cut from a real photograph with a known answer, the LiveView following it, and
// EndOfFlight from a record and a solution alone, with fakes for the session's and the live view's sides.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <opencv2/imgcodecs.hpp>

#include "core/pipeline/end_of_flight.h"
#include "core/pipeline/finish_flight.h"
#include "core/pipeline/flight_session.h"
#include "core/pipeline/live_view.h"
#include "core/session/session_dir.h"
#include "tests/session_test_util.h"
#include "tests/test_image.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;

// Under emulation (qemu-aarch64) the photograph, the crops and their offsets are half the size (tests/test_env.h):
// the same flight, a quarter of the pixels to detect.
const double kScale = test::EmulationImageScale();
const int kCropWidth = static_cast<int>(320 * kScale);
const int kCropHeight = static_cast<int>(240 * kScale);
const double kMetresPerPixel = 0.1 / kScale;  // of the photograph, north up
constexpr double kLat0 = 47.0, kLon0 = 9.0;   // on UTM zone 32's central meridian: grid north is north

// A serpentine flight of 2 strips over the bundled photograph: frame k is the crop whose top-left is Origin(k).
class PhotoFlight {
 public:
  PhotoFlight() : photo_(test::ScaledForEmulation(cv::imread(UAVM_TEST_DATA "/caliterra_small/images/IMG_9360.jpg"))) {}
  [[nodiscard]] bool ok() const { return !photo_.empty(); }
  [[nodiscard]] static int size() { return 10; }

  [[nodiscard]] static Vec2 Origin(int k) {
    const int strip = k / 5, i = k % 5;
    const int column = strip == 0 ? i : 4 - i;
    return kScale * Vec2(60 + 100 * column, 150 + 120 * strip);
  }
  // The frame as a camera source delivers it (no file: the session stores a JPEG), with GPS when `gps`.
  [[nodiscard]] Frame At(int k, bool gps) const {
    const Vec2 o = Origin(k);
    Frame f;
    f.image = photo_(cv::Rect(static_cast<int>(std::lround(o.x())), static_cast<int>(std::lround(o.y())), kCropWidth,
                              kCropHeight))
                  .clone();
    f.original_size = f.image.size();
    f.source_name = "crop_" + std::to_string(k) + ".jpg";
    f.timestamp_ns = 1'000'000'000LL * (k + 1);
    if (gps) {
      const Vec2 c = o + Vec2(0.5 * (kCropWidth - 1), 0.5 * (kCropHeight - 1));
      f.metadata.latitude_deg = kLat0 - c.y() * kMetresPerPixel / 111320.0;
      f.metadata.longitude_deg = kLon0 + c.x() * kMetresPerPixel / (111320.0 * std::cos(kLat0 * M_PI / 180.0));
    }
    return f;
  }

 private:
  cv::Mat photo_;
};

// Frame k's offset from frame 0 as the solved maps put it (frame pixels: the crops share one scale).
Vec2 SolvedOffset(const RegistrationEngine& engine, int k) {
  const Vec2 c(0.5 * (kCropWidth - 1), 0.5 * (kCropHeight - 1));
  return Apply(engine.mosaic_from_work(0).inverse() * engine.mosaic_from_work(k), c) - c;
}

class SessionDir {
 public:
  explicit SessionDir(const std::string& name) {
    const fs::path dir = fs::temp_directory_path() / ("uavm_onboard_session_" + name + "_" + std::to_string(getpid()));
    fs::remove_all(dir);
    std::string error;
    EXPECT_TRUE(PrepareSessionDir(dir.string(), &paths_, &error)) << error;
  }
  ~SessionDir() { fs::remove_all(paths_.root); }
  [[nodiscard]] const SessionPaths& paths() const { return paths_; }

 private:
  SessionPaths paths_;
};

PipelineOptions TestOptions() {
  PipelineOptions o;
  o.preview_every = 1;
  o.write_products = false;
  return o;
}

std::unique_ptr<FlightSession> NewSession(const PipelineOptions& options, const SessionPaths& paths) {
  std::string error;
  auto session = FlightSession::Create(options, paths, &error);
  EXPECT_NE(session, nullptr) << error;
  return session;
}

// frames/ read back with OpenCV, in file-name order (the program's reader is hal's replay).
class DirectoryFrames final : public StoredFrameReader {
 public:
  bool Open(const std::string& dir, std::string* error) override {
    for (const auto& e : fs::directory_iterator(dir)) files_.push_back(e.path());
    std::sort(files_.begin(), files_.end());
    if (files_.empty()) *error = "no frames in " + dir;
    return !files_.empty();
  }
  Status Next(Frame* frame) override {
    if (next_ >= files_.size()) return Status::kEnd;
    const fs::path& p = files_[next_++];
    *frame = Frame{};
    frame->image = cv::imread(p.string());
    frame->source_name = p.filename().string();
    frame->original_size = frame->image.size();
    return frame->image.empty() ? Status::kUnreadable : Status::kFrame;
  }

 private:
  std::vector<fs::path> files_;
  size_t next_ = 0;
};

// Every frame of a flight keeps its record to the end: it derives its resize and holds metadata only when there is
// some.
TEST(SessionFrameTest, DerivesItsResizeAndHoldsMetadataOnlyWhenTheFrameHadSome) {
  SessionFrame f;
  f.original_size = cv::Size(4000, 3000);
  f.work_size = cv::Size(1000, 750);
  // Pixel centres: the images' outer edges meet.
  EXPECT_LT((Apply(f.work_from_original(), Vec2(3999.5, 2999.5)) - Vec2(999.5, 749.5)).norm(), 1e-12);
  EXPECT_LT((Apply(f.work_from_original(), Vec2(-0.5, -0.5)) - Vec2(-0.5, -0.5)).norm(), 1e-12);
  f.set_metadata(FrameMetadata{});
  EXPECT_TRUE(f.metadata().Empty());
  FrameMetadata gps;
  gps.latitude_deg = 50.8;
  gps.longitude_deg = -0.14;
  f.set_metadata(gps);
  ASSERT_TRUE(f.metadata().HasGps());
  EXPECT_EQ(*f.metadata().latitude_deg, 50.8);
  FrameMetadata camera_only;
  camera_only.model = "FC6310";
  f.set_metadata(camera_only);
  EXPECT_FALSE(f.metadata().HasGps());
  EXPECT_EQ(f.metadata().model, "FC6310");
  f.set_metadata(FrameMetadata{});
  EXPECT_TRUE(f.metadata().Empty());
  // Two names, two sizes, a time and a pointer: no 3x3 map, no 240-byte metadata in every frame's record.
  EXPECT_LE(sizeof(SessionFrame), 112u);
}

TEST(FlightSessionTest, StoresJournalsAndRegistersAFlightWhoseSolveMatchesTheTruth) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir dir("register");
  auto session = NewSession(TestOptions(), dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk) << error;
  std::vector<int> heard;
  Connection c = session->OnFrameRegistered([&](const RegisteredFrame& f) {
    heard.push_back(f.id);
    EXPECT_EQ(f.work_bgr->size(), cv::Size(kCropWidth, kCropHeight));
  });
  for (int k = 0; k < PhotoFlight::size(); ++k)
    EXPECT_EQ(session->AddFrame(flight.At(k, false)), FrameOutcome::kRegistered) << "frame " << k;
  EXPECT_EQ(heard, std::vector<int>({0, 1, 2, 3, 4, 5, 6, 7, 8, 9}));
  EXPECT_TRUE(session->storage_failure().empty());
  // Every frame's bytes and its journal line are in the session (what a resumed run reads).
  ASSERT_EQ(session->record().size(), 10u);
  for (const SessionFrame& f : session->record().frames()) {
    EXPECT_TRUE(fs::exists(f.stored_file)) << f.stored_file;
    EXPECT_TRUE(f.metadata().Empty());  // frames without GPS or EXIF
  }
  JournalContents journal;
  ASSERT_TRUE(ReadJournal(dir.paths().Join("journal.jsonl"), &journal, &error)) << error;
  EXPECT_EQ(journal.frames.size(), 10u);

  const Solution solution = session->Solve();
  ASSERT_TRUE(solution.ok) << solution.failure;
  EXPECT_EQ(solution.component.size(), 10u);
  for (int k = 1; k < PhotoFlight::size(); ++k)
    EXPECT_LT((SolvedOffset(session->record().engine(), k) - (PhotoFlight::Origin(k) - PhotoFlight::Origin(0))).norm(),
              0.5)
        << "frame " << k;
}

TEST(FlightSessionTest, AResumedSessionRegistersTheJournalsFramesAgainAndContinuesExactly) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir whole_dir("whole"), resumed_dir("resumed");
  std::string error;
  auto whole = NewSession(TestOptions(), whole_dir.paths());
  ASSERT_EQ(whole->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  for (int k = 0; k < PhotoFlight::size(); ++k) (void)whole->AddFrame(flight.At(k, false));
  {
    auto interrupted = NewSession(TestOptions(), resumed_dir.paths());
    ASSERT_EQ(interrupted->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
    for (int k = 0; k < 6; ++k) (void)interrupted->AddFrame(flight.At(k, false));
    interrupted->RecordSkipped("broken.jpg", "not an image");
  }
  auto resumed = NewSession(TestOptions(), resumed_dir.paths());
  DirectoryFrames stored;
  ASSERT_EQ(resumed->Start(true, &stored, &error), FlightSession::StartStatus::kOk) << error;
  EXPECT_EQ(resumed->frames_in(), 6u);
  EXPECT_EQ(resumed->seen().count("crop_5.jpg"), 1u);
  EXPECT_EQ(resumed->seen().count("broken.jpg"), 1u);
  EXPECT_EQ(resumed->record().skipped().size(), 1u);
  for (int k = 6; k < PhotoFlight::size(); ++k) (void)resumed->AddFrame(flight.At(k, false));
  // The same frames, the same features (read back, not detected again): the same registration. The stored frames
  // are JPEGs of the crops, so the resumed run's working images differ a little from the uninterrupted run's and only
  // the sub-pixel refinement could see it; the maps agree far below a pixel.
  for (int k = 1; k < PhotoFlight::size(); ++k)
    EXPECT_LT((SolvedOffset(resumed->record().engine(), k) - SolvedOffset(whole->record().engine(), k)).norm(), 0.05)
        << "frame " << k;
  // A journal that names a frame frames/ does not have: the resume stops with the reason, nothing registered.
  const SessionDir broken_dir("broken");
  {
    SessionJournal journal;
    ASSERT_TRUE(journal.Open(broken_dir.paths().Join("journal.jsonl"), false, 0, 1, &error)) << error;
    ASSERT_TRUE(journal.AddFrame(JournalFrame{0, "a.jpg", "000000_a.jpg", 1, kCropWidth, kCropHeight}, &error));
  }
  auto broken = NewSession(TestOptions(), broken_dir.paths());
  DirectoryFrames none;
  EXPECT_EQ(broken->Start(true, &none, &error), FlightSession::StartStatus::kOutputError);
  EXPECT_EQ(broken->frames_in(), 0u);
  // A file that is no journal at all: a usage error (the wrong --out), nothing written over it.
  const SessionDir foreign_dir("foreign");
  std::ofstream(foreign_dir.paths().Join("journal.jsonl")) << "not a journal\n";
  auto foreign = NewSession(TestOptions(), foreign_dir.paths());
  EXPECT_EQ(foreign->Start(true, &none, &error), FlightSession::StartStatus::kBadJournal);
}

TEST(FlightSessionTest, AFrameTheSessionCannotStoreFailsAndStopsTheFlightWithoutAnEvent) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir dir("storage");
  auto session = NewSession(TestOptions(), dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  int events = 0;
  Connection c = session->OnFrameRegistered([&](const RegisteredFrame&) { ++events; });
  EXPECT_EQ(session->AddFrame(flight.At(0, false)), FrameOutcome::kRegistered);
  // frames/ gone and a file in its place (root ignores permissions: a file is a storage failure for anyone).
  fs::remove_all(dir.paths().frames());
  std::ofstream(dir.paths().frames()) << "not a directory";
  EXPECT_EQ(session->AddFrame(flight.At(1, false)), FrameOutcome::kFailed);
  EXPECT_FALSE(session->storage_failure().empty());
  EXPECT_EQ(events, 1);
  EXPECT_FALSE(session->record().engine().frame(1).failure.empty());
}

TEST(FlightSessionTest, AFrameOfOneColourIsKeptOnlyWhenItsPositionCanPlaceItWhateverTheSource) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir dir("uniform");
  auto session = NewSession(TestOptions(), dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  (void)session->AddFrame(flight.At(0, true));
  const auto uniform = [&](const std::string& name, cv::Scalar colour, bool gps) {
    Frame f = flight.At(1, gps);  // a camera's frame: no file behind it
    f.image.setTo(colour);
    f.source_name = name;
    return f;
  };
  // Calm water: nothing to match, but its GPS places it (bridging): kept, with an id.
  EXPECT_NE(session->AddFrame(uniform("water_gps.jpg", cv::Scalar(120, 90, 60), true)), FrameOutcome::kRegistered);
  EXPECT_EQ(session->record().size(), 2u);
  // The same without a position, and a lens cap even with one: skipped, no id, journaled as skipped.
  (void)session->AddFrame(uniform("water.jpg", cv::Scalar(120, 90, 60), false));
  (void)session->AddFrame(uniform("cap.jpg", cv::Scalar(3, 3, 3), true));
  EXPECT_EQ(session->record().size(), 2u);
  ASSERT_EQ(session->record().skipped().size(), 2u);
  EXPECT_EQ(session->record().skipped()[0].file, "water.jpg");
  EXPECT_EQ(session->record().skipped()[0].reason.rfind("uniform frame (one colour", 0), 0u);
  EXPECT_EQ(session->record().skipped()[1].reason.rfind("uniform frame (black or saturated)", 0), 0u);
  JournalContents journal;
  ASSERT_TRUE(ReadJournal(dir.paths().Join("journal.jsonl"), &journal, &error)) << error;
  EXPECT_EQ(journal.frames.size(), 2u);
  EXPECT_EQ(journal.skipped.size(), 2u);
}

TEST(FlightSessionTest, FollowersAnswerHintRequestsWithEachFramesMetadataAndDisconnectThemselves) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir dir("hints");
  auto session = NewSession(TestOptions(), dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  std::vector<double> latitudes;
  {
    Connection asked = session->OnHintRequest([&](HintRequest& r) { latitudes.push_back(*r.metadata->latitude_deg); });
    (void)session->AddFrame(flight.At(0, true));
    (void)session->AddFrame(flight.At(1, true));
  }
  (void)session->AddFrame(flight.At(2, true));  // the follower has gone: not asked
  ASSERT_EQ(latitudes.size(), 2u);
  EXPECT_DOUBLE_EQ(latitudes[1], *flight.At(1, true).metadata.latitude_deg);
}

TEST(LiveViewTest, FollowsTheFlightWithPicturesAGeoreferenceAndHintsWhereFramesAre) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir dir("live");
  auto session = NewSession(TestOptions(), dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  auto view = std::make_unique<LiveView>(session->options(), dir.paths(), &session->record(), &session->lens(),
                                         &session->stage_stats());
  view->Follow(session.get());
  int pictures = 0;
  bool georeferenced = false;
  Connection c = view->OnPreview([&](std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> g) {
    ++pictures;
    EXPECT_GT(jpeg->size(), 1000u);
    georeferenced = georeferenced || g->value("georeferenced", false);
  });
  for (int k = 0; k < 8; ++k) EXPECT_EQ(session->AddFrame(flight.At(k, true)), FrameOutcome::kRegistered);
  EXPECT_EQ(pictures, 8);  // preview_every 1
  EXPECT_TRUE(fs::exists(dir.paths().Join("live.jpg")));
  ASSERT_TRUE(georeferenced);
  EXPECT_TRUE(fs::exists(dir.paths().Join("live.jgw")));
  // The hint for the next frame, from its GPS through the live georeference: where the engine then puts it.
  const Frame next = flight.At(8, true);
  const std::optional<PositionHint> hint = view->HintFor(next.metadata);
  ASSERT_TRUE(hint.has_value());
  EXPECT_EQ(session->AddFrame(next), FrameOutcome::kRegistered);
  const RegistrationEngine& engine = session->record().engine();
  const Vec2 placed = Apply(engine.mosaic_from_work(8), Vec2(0.5 * (kCropWidth - 1), 0.5 * (kCropHeight - 1)));
  EXPECT_LT((hint->centre - placed).norm(), 3.0);
  EXPECT_GT(session->stage_stats().Get("preview").count, 0u);
  // The view goes first: the session flies on without it (its connections went with it).
  view.reset();
  EXPECT_EQ(session->AddFrame(flight.At(9, true)), FrameOutcome::kRegistered);
  EXPECT_EQ(pictures, 9);
}

// The session's side of the end, recorded.
class FakeSessionEnd final : public SessionEnd {
 public:
  void EnterPhase(const std::string& name) override { phases.push_back(name); }
  void ComposeEnd() override { phases.push_back("compose_end"); }
  bool WriteEdgeTables(const IdSet& in_component, std::string*) override {
    tables_for = in_component.size();
    return true;
  }
  void DropEdgeRecords() override { phases.push_back("edges_dropped"); }
  nlohmann::json Report(const Solution&, const CompositeResult& composite) const override {
    return {{"from_session", true}, {"frames_blended_seen", composite.frames_used}};
  }
  std::vector<std::string> phases;
  size_t tables_for = 0;
};

class FakeLive final : public FinalMapListener {
 public:
  TileOptions FinalTileOptions(bool) const override { return {}; }
  void FinalTiles(const TileSet* tiles, int frames) override { calls.emplace_back(tiles != nullptr, frames); }
  void WriteLastPreview() override { ++previews; }
  nlohmann::json Report() const override { return {{"fake", true}}; }
  std::vector<std::pair<bool, int>> calls;
  int previews = 0;
};

TEST(EndOfFlightTest, WritesTheMapFromARecordAndASolutionAlone) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  // A record and a solution: made here by a session (no program), then handed to the end with fakes around it.
  const SessionDir dir("end");
  PipelineOptions options = TestOptions();
  options.write_products = true;
  auto session = NewSession(options, dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  for (int k = 0; k < PhotoFlight::size(); ++k) (void)session->AddFrame(flight.At(k, k < 3));
  const Solution solution = session->Solve();
  ASSERT_TRUE(solution.ok);
  FakeSessionEnd fake_session;
  FakeLive fake_live;
  EndOfFlight::Inputs in;
  in.record = &session->record();
  in.solution = &solution;
  in.lens = &session->lens();
  in.session = &fake_session;
  in.live = &fake_live;
  in.additions.report_sections = {{"telemetry", {{"kind", "test"}}}};
  in.additions.config_yaml = "telemetry:\n  latency_ms: 5\n";
  EndOfFlight end(session->options(), dir.paths(), std::move(in));
  ASSERT_TRUE(end.Run(&error)) << error;

  EXPECT_EQ(fake_session.phases,
            std::vector<std::string>({"radiometry", "outputs", "edges_dropped", "compose", "compose_end", "products"}));
  EXPECT_EQ(fake_session.tables_for, 10u);
  // transforms.csv: every frame in the map, their offsets on the canvas as in the photograph (the canvas is
  // georeferenced by 3 frames' GPS and turned north-up: the photograph is north-up already).
  std::vector<TransformRow> rows;
  std::string text;
  ASSERT_TRUE(ReadTextFile(dir.paths().Join("transforms.csv"), &text, &error)) << error;
  ASSERT_TRUE(ParseTransformsCsv(text, &rows, &error)) << error;
  ASSERT_EQ(rows.size(), 10u);
  const Vec2 c(0.5 * (kCropWidth - 1), 0.5 * (kCropHeight - 1));
  const double scale = options.mosaic_scale;
  for (const TransformRow& r : rows) {
    EXPECT_TRUE(r.registered);
    const Vec2 on_canvas = Apply(r.mosaic_from_frame, c) - Apply(rows[0].mosaic_from_frame, c);
    const Vec2 truth = scale * (PhotoFlight::Origin(r.index) - PhotoFlight::Origin(0));
    EXPECT_LT((on_canvas - truth).norm(), 1.0) << "frame " << r.index;
  }
  const cv::Mat quicklook = cv::imread(dir.paths().Join("mosaic.png"));
  EXPECT_FALSE(quicklook.empty());
  EXPECT_TRUE(fs::exists(dir.paths().Join("mosaic.tif")));
  // The live view was handed the final tiles once made, and wrote its last picture.
  ASSERT_FALSE(fake_live.calls.empty());
  EXPECT_TRUE(fake_live.calls.front().first);
  EXPECT_EQ(fake_live.calls.front().second, 10);
  EXPECT_EQ(fake_live.previews, 1);
  const nlohmann::json report = test::ReadJson(dir.paths().Join("report.json"));
  EXPECT_TRUE(report.value("from_session", false));
  EXPECT_EQ(report["frames_blended_seen"], report["mosaic"]["frames_blended"]);
  EXPECT_EQ(report["registered"], 10);
  EXPECT_EQ(report["live_tiles"]["fake"], true);
  EXPECT_EQ(report["telemetry"]["kind"], "test");
  EXPECT_TRUE(report["georef"]["georeferenced"].get<bool>());
  std::string config_yaml;
  ASSERT_TRUE(ReadTextFile(dir.paths().Join("config.yaml"), &config_yaml, &error));
  EXPECT_NE(config_yaml.find("latency_ms: 5"), std::string::npos);
}

TEST(EndOfFlightTest, FinishFlightRunsTheWholeEndAndTellsTheJournal) {
  const PhotoFlight flight;
  ASSERT_TRUE(flight.ok());
  const SessionDir dir("finish");
  auto session = NewSession(TestOptions(), dir.paths());
  std::string error;
  ASSERT_EQ(session->Start(false, nullptr, &error), FlightSession::StartStatus::kOk);
  for (int k = 0; k < 4; ++k) (void)session->AddFrame(flight.At(k, false));
  FlightSummary summary;
  ASSERT_TRUE(FinishFlight(session.get(), nullptr, OutputAdditions{}, &summary, &error)) << error;
  EXPECT_EQ(summary.registered, 4);
  JournalContents journal;
  ASSERT_TRUE(ReadJournal(dir.paths().Join("journal.jsonl"), &journal, &error));
  EXPECT_TRUE(journal.finished);
  const nlohmann::json report = test::ReadJson(dir.paths().Join("report.json"));
  EXPECT_EQ(report["registered"], 4);
  EXPECT_EQ(report["frames_in"], 4);
  EXPECT_EQ(report["live_tiles"]["enabled"], false);
}

}  // namespace
}  // namespace uavm
