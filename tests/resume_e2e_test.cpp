// Crash safety, end to end: the onboard binary is killed (SIGKILL) at points spread over a real flight, the
// compositing included, and resumed with --resume; every resumed session must end with every frame, the same
// registered set and the same maps as a run that was never interrupted. SIGTERM finishes cleanly.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <random>
#include <thread>

#include "core/session/journal.h"
#include "core/session/session_dir.h"
#include "tests/test_env.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
// The real flight; under emulation its first 8 frames (tests/test_env.h).
const test::FlightForTest& Flight() {
  static const test::FlightForTest flight(
      fs::path(UAVM_TEST_DATA) / "brighton_beach_small/images", 8,
      fs::temp_directory_path() / ("uavm_resume_flight_" + std::to_string(::getpid())));
  return flight;
}

fs::path TempDir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("uavm_resume_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

pid_t Start(const fs::path& out, bool resume) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    std::vector<std::string> args = {UAVM_ONBOARD_BIN, "--source", "replay:" + Flight().string(), "--out", out.string(),
                                     "--log-level",    "error"};
    if (resume) args.emplace_back("--resume");
    for (const auto& a : test::LightArgs()) args.push_back(a);  // natively too: resume does not depend on it
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  return pid;
}

// Waits for the child; kills it with `sig` after `after` seconds unless it ended before. Returns the wait status.
int WaitOrSignal(pid_t pid, double after, int sig) {
  const auto deadline = Clock::now() + std::chrono::duration<double>(after);
  int status = 0;
  for (;;) {
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    if (r == pid) return status;
    if (Clock::now() >= deadline) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  ::kill(pid, sig);
  ::waitpid(pid, &status, 0);
  return status;
}

// Kills the child with SIGKILL `delay` seconds after `ready()` first holds (the kill point is an event of the run,
// not a time: the machine may be busy). Returns the wait status.
template <typename Ready>
int KillWhen(pid_t pid, Ready ready, double delay, int sig = SIGKILL) {
  int status = 0;
  for (;;) {
    if (::waitpid(pid, &status, WNOHANG) == pid) return status;
    if (ready()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return WaitOrSignal(pid, delay, sig);
}

size_t JournaledFrames(const fs::path& journal) {
  std::ifstream in(journal);
  size_t n = 0;
  for (std::string line; std::getline(in, line);) n += line.find("\"type\":\"frame\"") != std::string::npos;
  return n;
}

struct Session {
  std::map<std::string, Mat3> maps;  // registered frames
  std::map<std::string, cv::Size> sizes;
  nlohmann::json report;
};

Session Load(const fs::path& out) {
  Session s;
  std::string text;
  std::string err;
  EXPECT_TRUE(ReadTextFile((out / "transforms.csv").string(), &text, &err)) << err;
  std::vector<TransformRow> rows;
  EXPECT_TRUE(ParseTransformsCsv(text, &rows, &err)) << err;
  for (const auto& r : rows)
    if (r.registered) s.maps[r.filename] = r.mosaic_from_frame;
  std::ifstream in(out / "report.json");
  s.report = nlohmann::json::parse(in, nullptr, false);
  std::string frames;
  EXPECT_TRUE(ReadTextFile((out / "frames.csv").string(), &frames, &err));
  std::istringstream lines(frames);
  std::string line;
  std::getline(lines, line);
  while (std::getline(lines, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) cells.push_back(c);
    if (cells.size() > 4) s.sizes[cells[1]] = cv::Size(std::stoi(cells[3]), std::stoi(cells[4]));
  }
  return s;
}

// Largest distance between where the two sessions put a frame's corners, over all frames.
double MaxCornerDistance(const Session& a, const Session& b) {
  double worst = 0;
  for (const auto& [name, m] : a.maps) {
    const auto it = b.maps.find(name);
    if (it == b.maps.end()) return 1e9;
    const cv::Size size = a.sizes.at(name);
    for (const Vec2& c : {Vec2(0, 0), Vec2(size.width, 0), Vec2(0, size.height), Vec2(size.width, size.height)})
      worst = std::max(worst, (Apply(m, c) - Apply(it->second, c)).norm());
  }
  return worst;
}

TEST(ResumeTest, KilledAnywhereResumesToTheSameMosaic) {
  ASSERT_GT(Flight().frames(), 0);  // made here, before any fork: children only read it
  // The uninterrupted reference, timed from the outside.
  const fs::path ref_dir = TempDir("reference");
  const int ref_status = WaitOrSignal(Start(ref_dir, false), 600, SIGKILL);
  ASSERT_TRUE(WIFEXITED(ref_status) && WEXITSTATUS(ref_status) == 0);
  const Session ref = Load(ref_dir);
  const size_t inputs = static_cast<size_t>(Flight().frames());
  ASSERT_EQ(ref.maps.size(), inputs);
  // Where the compositing (tile writes) happens in that time line: the report's wall time ends with it.
  const double compose_s = ref.report["composite_ms"].get<double>() / 1000.0;

  // The finished mosaic a killed run may already have renamed into place must be this one, whole.
  const cv::Size ref_mosaic = cv::imread((ref_dir / "mosaic.tif").string(), cv::IMREAD_UNCHANGED).size();
  ASSERT_FALSE(ref_mosaic.empty());

  // Kill points: five after a random number of accepted frames (spread over the flight), two while tiles are being
  // written (mosaic.tiled.tif.part, the compositor's file before the COG copy, exists), each with a random delay.
  // Under emulation, where each run takes minutes, two and one: early and late in the flight, and the compositing.
  const size_t flight_kills = test::Emulated() ? 2 : 5;
  const size_t compositing_kills = test::Emulated() ? 1 : 2;
  std::mt19937 rng(20261121);
  struct KillPoint {
    size_t after_frames;  // 0: during the compositing
    double delay_s;
  };
  std::vector<KillPoint> points;
  for (size_t slot = 0; slot < flight_kills; ++slot) {
    std::uniform_int_distribution<size_t> frames(1 + slot * (inputs - 1) / flight_kills,
                                                 (slot + 1) * (inputs - 1) / flight_kills);
    points.push_back({frames(rng), std::uniform_real_distribution<double>(0.0, 0.2)(rng)});
  }
  for (size_t k = 0; k < compositing_kills; ++k)
    points.push_back({0, std::uniform_real_distribution<double>(0.0, 0.6 * compose_s)(rng)});

  int killed = 0;
  int killed_while_compositing = 0;
  for (size_t k = 0; k < points.size(); ++k) {
    const KillPoint& point = points[k];
    SCOPED_TRACE("kill point " + std::to_string(k));
    const fs::path dir = TempDir("kill" + std::to_string(k));
    const auto ready = [&] {
      return point.after_frames > 0 ? JournaledFrames(dir / "journal.jsonl") >= point.after_frames
                                    : fs::exists(dir / "mosaic.tiled.tif.part");
    };
    const int status = KillWhen(Start(dir, false), ready, point.delay_s);
    const bool was_killed = WIFSIGNALED(status);
    if (was_killed) {
      ++killed;
      if (point.after_frames == 0) ++killed_while_compositing;
    }
    // What the killed run left must be readable: the journal parses, no half-written mosaic under its final name
    // (the kill may land after the mosaic's rename and before report.json: the mosaic is then whole).
    JournalContents journal;
    std::string err;
    ASSERT_TRUE(ReadJournal((dir / "journal.jsonl").string(), &journal, &err)) << err;
    if (fs::exists(dir / "mosaic.tif")) {
      EXPECT_EQ(cv::imread((dir / "mosaic.tif").string(), cv::IMREAD_UNCHANGED).size(), ref_mosaic);
    }
    const size_t journaled = journal.frames.size();
    // Resume until the flight is complete (a resume may itself be interrupted in real life; here it runs through).
    const int resumed_status = WaitOrSignal(Start(dir, true), 600, SIGKILL);
    ASSERT_TRUE(WIFEXITED(resumed_status)) << "resume crashed";
    ASSERT_EQ(WEXITSTATUS(resumed_status), 0);
    const Session s = Load(dir);
    EXPECT_EQ(s.report["frames_decoded"].get<size_t>(), inputs) << "frames lost";
    EXPECT_EQ(s.report["resumed_frames"].get<size_t>(), journaled);
    ASSERT_EQ(s.maps.size(), ref.maps.size());
    for (const auto& [name, m] : ref.maps) EXPECT_EQ(s.maps.count(name), 1u) << name << " not registered";
    const double diff = MaxCornerDistance(ref, s);
    EXPECT_LE(diff, 0.5);
    std::printf(
        "kill %zu (%s, +%.2f s): %zu frames journaled, resumed to %zu/%zu registered, max corner "
        "difference %.4f px\n",
        k, !was_killed ? "run ended first" : (point.after_frames > 0 ? "flight" : "tile writes"), point.delay_s,
        journaled, s.maps.size(), inputs, diff);
    // Each frame is journaled once, however often the session was interrupted.
    ASSERT_TRUE(ReadJournal((dir / "journal.jsonl").string(), &journal, &err)) << err;
    EXPECT_EQ(journal.frames.size(), inputs);
    EXPECT_TRUE(journal.finished);
    EXPECT_EQ(std::distance(fs::directory_iterator(dir / "frames"), fs::directory_iterator{}),
              static_cast<long>(inputs));
    fs::remove_all(dir);
  }
  EXPECT_GE(killed, static_cast<int>(points.size()) - 1) << "kill points must land before the run ends";
  EXPECT_GE(killed_while_compositing, 1);
  fs::remove_all(ref_dir);
}

TEST(ResumeTest, SigtermFinishesWithWhatWasReceived) {
  ASSERT_GT(Flight().frames(), 0);  // made here, before any fork: children only read it
  const fs::path dir = TempDir("term");
  const int status = KillWhen(
      Start(dir, false), [&] { return JournaledFrames(dir / "journal.jsonl") >= 6; }, 0.0, SIGTERM);
  ASSERT_TRUE(WIFEXITED(status)) << "SIGTERM must not kill the process";
  EXPECT_EQ(WEXITSTATUS(status), 0);
  const Session s = Load(dir);
  const size_t got = s.report["frames_decoded"].get<size_t>();
  EXPECT_GT(got, 0u);
  EXPECT_EQ(s.maps.size(), got);  // every received frame registered and composited
  EXPECT_TRUE(fs::exists(dir / "mosaic.tif"));
  JournalContents journal;
  std::string err;
  ASSERT_TRUE(ReadJournal((dir / "journal.jsonl").string(), &journal, &err));
  EXPECT_TRUE(journal.finished);
  EXPECT_LT(got, static_cast<size_t>(Flight().frames()));  // the signal stopped the capture early
  fs::remove_all(dir);
}

}  // namespace
}  // namespace uavm
