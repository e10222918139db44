#pragma once
#include <cstdint>
#include <cstdio>
#include <string>

#include "core/graph/match_graph.h"

namespace uavm {

// Append-only file of every edge's correspondences (edges.bin in the session directory), so that the flight keeps
// in memory only the points the solves of its newest frames can use: an edge whose frames have both left the solve
// window gives its points back, and the end of the flight reads them again. Records carry a checksum; a reader
// never trusts a record it cannot verify.
//
// Record: magic "UEDG", int32 src, int32 tgt, uint32 n, uint32 n_holdout, uint32 fnv1a(payload), then
// (n + n_holdout) x float32 {x_src, y_src, x_tgt, y_tgt} in working-resolution pixels.
class EdgeStore {
 public:
  EdgeStore() = default;
  ~EdgeStore();
  EdgeStore(const EdgeStore&) = delete;
  EdgeStore& operator=(const EdgeStore&) = delete;

  // Creates (truncates) the file. False with a reason when it cannot be written.
  [[nodiscard]] bool Open(const std::string& path, std::string* error);
  [[nodiscard]] bool is_open() const { return file_ != nullptr; }
  // Appends the edge's points (float, as the edge holds them: a reload gives the same numbers); sets edge->stored_at
  // on success.
  [[nodiscard]] bool Append(Edge* edge, std::string* error);
  // Refills an edge's points from its record (no-op when they are resident).
  [[nodiscard]] bool Load(Edge* edge, std::string* error);
  // Frees an edge's points if they are on disk; returns the bytes given back.
  size_t Release(Edge* edge);
  void Close();
  [[nodiscard]] uint64_t bytes_written() const { return bytes_written_; }

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  uint64_t bytes_written_ = 0;
};

// Bytes an edge's resident points take.
[[nodiscard]] size_t PointBytes(const Edge& edge);

}  // namespace uavm
