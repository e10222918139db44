#pragma once
// What a test needs to know about where it runs. The aarch64 suite runs under qemu-user (CMAKE_CROSSCOMPILING_EMULATOR,
// UAVM_EMULATED=1 set by the cross toolchain's emulator command), where SIFT runs 35-50x slower than natively: heavy
// tests then do less work (fewer frames), so the whole suite still runs.
#include <sys/wait.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

namespace uavm::test {

inline bool Emulated() {
  const char* v = std::getenv("UAVM_EMULATED");
  return v != nullptr && std::string(v) == "1";
}

// Extra uavmosaic-onboard options under emulation: a 320 px working copy (the default is 1000 px), detected once
// (--min-features 0: no second SIFT pass at a lower threshold when a small frame yields under 1500 keypoints), and no
// web tiles or KMZ (--no-products; mosaic.tif stays a COG) unless the test is about them.
// Under qemu SIFT is most of an onboard run: on three frames, 105 s of 127 s at 1000 px; at 320 px 37 s with the
// second pass, 18 s without; the tiles and the KMZ of those three frames then take 17 s more. Checked natively, where
// the results are the same bytes as under qemu (scripts/test_aarch64.sh compares them): every frame of
// brighton_beach_small (18) and caliterra_small (20) still registers this way, and the end-to-end tests' thresholds
// hold. scripts/test_aarch64.sh's parity step runs the whole flight under emulation.
enum class Products { kSkipUnderEmulation, kWrite };
// LightArgs(): the same reduced settings on every build, for end-to-end tests whose point is not registration at the
// product's working size (crash safety and resume: the journal, the kill points and the comparison with an
// uninterrupted run do not depend on it); natively they make such a run ~3x cheaper.
inline std::vector<std::string> LightArgs() {
  return {"--work-size", "320", "--min-features", "0", "--no-products"};
}
inline std::vector<std::string> EmulationArgs(Products products = Products::kSkipUnderEmulation) {
  if (!Emulated()) return {};
  std::vector<std::string> args = LightArgs();
  if (products == Products::kWrite) args.pop_back();
  return args;
}
inline std::string EmulationArgsString(Products products = Products::kSkipUnderEmulation) {
  std::string s;
  for (const auto& a : EmulationArgs(products)) s += " " + a;
  return s;
}

// The flight an end-to-end test replays: natively `images` itself; under emulation a folder under `scratch` holding
// (symlinks to) its first `emulated_frames` images in name order, so the test flies a shorter stretch of the same
// flight (every frame of the whole flight is registered under emulation by scripts/test_aarch64.sh's parity step).
// Owns `scratch`: removed with it.
class FlightForTest {
 public:
  FlightForTest(const std::filesystem::path& images, size_t emulated_frames, std::filesystem::path scratch)
      : scratch_(std::move(scratch)) {
    namespace fs = std::filesystem;
    if (!Emulated()) {
      path_ = images;
    } else {
      std::vector<fs::path> files;
      for (const auto& e : fs::directory_iterator(images))
        if (e.is_regular_file()) files.push_back(e.path());
      std::sort(files.begin(), files.end());
      path_ = scratch_ / "emulated_flight";
      fs::remove_all(path_);
      fs::create_directories(path_);
      for (size_t i = 0; i < files.size() && i < emulated_frames; ++i)
        fs::create_symlink(files[i], path_ / files[i].filename());
    }
    for (const auto& e : fs::directory_iterator(path_)) frames_ += e.is_regular_file() ? 1 : 0;
  }
  ~FlightForTest() {
    std::error_code ignored;
    if (Emulated()) std::filesystem::remove_all(scratch_, ignored);
  }
  FlightForTest(const FlightForTest&) = delete;
  FlightForTest& operator=(const FlightForTest&) = delete;

  const std::filesystem::path& path() const { return path_; }
  std::string string() const { return path_.string(); }
  int frames() const { return frames_; }

 private:
  std::filesystem::path scratch_;
  std::filesystem::path path_;
  int frames_ = 0;
};

// Unit tests that run SIFT on real frames scale them by this under emulation (same assertions, a quarter the pixels).
inline double EmulationImageScale() {
  return Emulated() ? 0.5 : 1.0;
}

#ifdef UAVM_ONBOARD_BIN
// Runs uavmosaic-onboard with `args` (shell syntax, redirections allowed) plus the emulation options, logging warnings
// only; returns its exit code, -1 when it did not exit normally.
inline int RunOnboard(const std::string& args, Products products = Products::kSkipUnderEmulation) {
  const std::string cmd =
      std::string(UAVM_ONBOARD_BIN) + " " + args + EmulationArgsString(products) + " --log-level warn";
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}
#endif

}  // namespace uavm::test
