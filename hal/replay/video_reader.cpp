#include "hal/replay/video_reader.h"

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <system_error>
#include <vector>

namespace uavm::hal {
namespace {

namespace fs = std::filesystem;

using OpenFn = VideoReader* (*)(const char*);

struct Module {
  OpenFn open = nullptr;
  std::string path;
};

constexpr const char* kModuleName = "libuavm_video_reader.so";

// Where the module may be, in the order tried.
std::vector<std::string> ModuleCandidates() {
  if (const char* env = std::getenv("UAVM_VIDEO_READER"); env != nullptr && *env != '\0') return {env};
  std::vector<std::string> paths;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) paths.push_back((exe.parent_path().parent_path() / "lib" / "uavmosaic" / kModuleName).string());
#ifdef UAVM_VIDEO_READER_BUILD_PATH
  paths.emplace_back(UAVM_VIDEO_READER_BUILD_PATH);
#endif
  return paths;
}

// The module's entry point from the first candidate that loads; none (and `why`) when none does. A module loaded
// once is reused (and never closed: the readers' code and vtables live in it); the candidates are read again on
// every call, so that UAVM_VIDEO_READER always decides.
Module LoadModule(std::string* why) {
  static std::mutex mutex;
  static std::map<std::string, OpenFn> loaded;
  std::lock_guard<std::mutex> lock(mutex);
  std::string tried;
  for (const std::string& path : ModuleCandidates()) {
    if (auto it = loaded.find(path); it != loaded.end()) return {it->second, path};
    std::error_code ec;
    if (!fs::exists(path, ec)) {
      tried += (tried.empty() ? "" : ", ") + path + " (missing)";
      continue;
    }
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      const char* e = dlerror();
      tried += (tried.empty() ? "" : ", ") + path + " (" + (e != nullptr ? e : "dlopen failed") + ")";
      continue;
    }
    if (auto open = reinterpret_cast<OpenFn>(dlsym(handle, "uavm_open_video")); open != nullptr) {
      loaded.emplace(path, open);
      return {open, path};
    }
    dlclose(handle);
    tried += (tried.empty() ? "" : ", ") + path + " (no uavm_open_video)";
  }
  *why = "video replay needs " + std::string(kModuleName) + " (OpenCV videoio); tried " + tried;
  return {};
}

}  // namespace

std::unique_ptr<VideoReader> OpenVideo(const std::string& path, std::string* error) {
  const Module module = LoadModule(error);
  if (module.open == nullptr) return nullptr;
  std::unique_ptr<VideoReader> reader(module.open(path.c_str()));
  if (!reader) *error = "cannot open video " + path + " (read through " + module.path + ")";
  return reader;
}

}  // namespace uavm::hal
