// Fuzzes the edges.bin record reader (EdgeStore::Load): the input is the file, the edge to load is the record at
// offset 0 (its src/tgt taken from the input so that the header check can pass). A record loads with the points
// its header declares or is refused with a message; never a crash.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "core/session/edge_store.h"

namespace {

const std::string& InputPath() {
  static const std::string path = "/tmp/uavm_fuzz_edges_" + std::to_string(::getpid()) + ".bin";
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = InputPath();
  uavm::EdgeStore store;
  std::string error;
  if (!store.Open(path, &error)) std::abort();  // creates the file empty
  // The fuzz input becomes the file's contents, behind the store's back (same file, nothing buffered yet).
  std::FILE* f = std::fopen(path.c_str(), "r+b");
  if (f == nullptr) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);

  uavm::Edge edge;
  int32_t ids[2] = {0, 0};
  if (size >= 12) std::memcpy(ids, data + 4, sizeof(ids));
  edge.src = ids[0];
  edge.tgt = ids[1];
  edge.stored_at = 0;
  edge.points_resident = false;
  if (!store.Load(&edge, &error)) {
    if (error.empty()) std::abort();
    return 0;
  }
  if (edge.points.float_count() != 4 * (edge.points.size() + edge.points.holdout_size())) std::abort();
  const size_t points = edge.points.size() + edge.points.holdout_size();
  if (24 + 16 * points > size) std::abort();
  return 0;
}
