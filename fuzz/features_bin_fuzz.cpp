// Fuzzes the features/NNNNNN.bin reader (ReadFeatures): arbitrary file contents load consistently or are refused,
// never a crash and never an allocation the file cannot back.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "core/session/feature_store.h"

namespace {

// One file per fuzzing process, rewritten for every input.
const std::string& InputPath() {
  static const std::string path = "/tmp/uavm_fuzz_features_" + std::to_string(::getpid()) + ".bin";
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = InputPath();
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);
  uavm::Features features;
  std::string error;
  if (!uavm::ReadFeatures(path, &features, &error)) {
    if (error.empty()) std::abort();
    return 0;
  }
  if (features.descriptors.rows != static_cast<int>(features.points.size())) std::abort();
  // What loaded came from the file: 16 header bytes, 8 per point and one per descriptor byte.
  if (16 + 8 * features.points.size() + features.descriptors.total() > size) std::abort();
  return 0;
}
