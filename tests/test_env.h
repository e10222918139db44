#pragma once
// What a test needs to know about where it runs. The aarch64 suite runs under qemu-user (CMAKE_CROSSCOMPILING_EMULATOR,
// UAVM_EMULATED=1 set by the cross toolchain's emulator command), where SIFT runs 35-50x slower than natively: heavy
// tests then do less work (fewer frames), so the whole suite still runs.
#include <sys/wait.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

namespace uavm::test {

inline bool Emulated() {
  const char* v = std::getenv("UAVM_EMULATED");
  return v != nullptr && std::string(v) == "1";
}

// Extra uavmosaic-onboard options under emulation: a 320 px working copy (the default is 1000 px), detected once
// (--min-features 0: no second SIFT pass at a lower threshold when a small frame yields under 1500 keypoints).
// Under qemu SIFT is most of an onboard run: on three frames, 105 s of 127 s at 1000 px; at 320 px 37 s with the
// second pass, 18 s without. Checked natively, where the results are the same bytes as under qemu
// (scripts/test_aarch64.sh compares them): every frame of brighton_beach_small (18) and caliterra_small (20) still
// registers this way, and the end-to-end tests' thresholds hold. The full-size run under emulation is
// scripts/test_aarch64.sh's parity step.
inline std::vector<std::string> EmulationArgs() {
  if (!Emulated()) return {};
  return {"--work-size", "320", "--min-features", "0"};
}
inline std::string EmulationArgsString() {
  std::string s;
  for (const auto& a : EmulationArgs()) s += " " + a;
  return s;
}

// Natively `images` itself; under emulation a folder under `scratch` holding (symlinks to) its first `emulated_frames`
// images in name order, so an end-to-end test flies a shorter stretch of the same flight (every frame of the whole
// flight is registered under emulation by scripts/test_aarch64.sh's parity step).
inline std::filesystem::path FlightForTest(const std::filesystem::path& images, size_t emulated_frames,
                                           const std::filesystem::path& scratch) {
  namespace fs = std::filesystem;
  if (!Emulated()) return images;
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(images))
    if (e.is_regular_file()) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  const fs::path out = scratch / "emulated_flight";
  fs::remove_all(out);
  fs::create_directories(out);
  for (size_t i = 0; i < files.size() && i < emulated_frames; ++i)
    fs::create_symlink(files[i], out / files[i].filename());
  return out;
}

// Unit tests that run SIFT on real frames scale them by this under emulation (same assertions, a quarter the pixels).
inline double EmulationImageScale() {
  return Emulated() ? 0.5 : 1.0;
}

// Images in a replay folder (FlightForTest's answer).
inline int CountFrames(const std::filesystem::path& dir) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) n += e.is_regular_file() ? 1 : 0;
  return n;
}

#ifdef UAVM_ONBOARD_BIN
// Runs uavmosaic-onboard with `args` (shell syntax, redirections allowed) plus the emulation options, logging warnings
// only; returns its exit code, -1 when it did not exit normally.
inline int RunOnboard(const std::string& args) {
  const std::string cmd = std::string(UAVM_ONBOARD_BIN) + " " + args + EmulationArgsString() + " --log-level warn";
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}
#endif

}  // namespace uavm::test
