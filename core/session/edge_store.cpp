#include "core/session/edge_store.h"

#include <array>
#include <cstring>
#include <vector>

namespace uavm {

namespace {

constexpr std::array<char, 4> kMagic = {'U', 'E', 'D', 'G'};
constexpr uint32_t kMaxPoints = 1u << 20;  // far above any edge: a guard against a corrupt count

struct RecordHeader {
  std::array<char, 4> magic;
  int32_t src;
  int32_t tgt;
  uint32_t n;
  uint32_t n_holdout;
  uint32_t checksum;
};
static_assert(sizeof(RecordHeader) == 24, "edges.bin header layout");

uint32_t Fnv1a(const void* data, size_t size) {
  uint32_t h = 2166136261u;
  const auto* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 16777619u;
  return h;
}

}  // namespace

EdgeStore::~EdgeStore() {
  Close();
}

bool EdgeStore::Open(const std::string& path, std::string* error) {
  Close();
  file_ = std::fopen(path.c_str(), "w+b");
  if (file_ == nullptr) {
    *error = "cannot create " + path;
    return false;
  }
  path_ = path;
  bytes_written_ = 0;
  return true;
}

void EdgeStore::Close() {
  if (file_ != nullptr) std::fclose(file_);
  file_ = nullptr;
}

bool EdgeStore::Append(Edge* edge, std::string* error) {
  if (file_ == nullptr) {
    *error = "edge store not open";
    return false;
  }
  // The edge's block is the record's payload as it is: nothing is copied to be written.
  const EdgePoints& points = edge->points;
  const size_t floats = points.float_count();
  RecordHeader h{kMagic,
                 edge->src,
                 edge->tgt,
                 static_cast<uint32_t>(points.size()),
                 static_cast<uint32_t>(points.holdout_size()),
                 Fnv1a(points.floats(), floats * sizeof(float))};
  // Reads seek elsewhere: every append goes to the end explicitly.
  if (std::fseek(file_, 0, SEEK_END) != 0) {
    *error = "seek failed: " + path_;
    return false;
  }
  const long offset = std::ftell(file_);
  const bool ok = offset >= 0 && std::fwrite(&h, sizeof(h), 1, file_) == 1 &&
                  (floats == 0 || std::fwrite(points.floats(), sizeof(float), floats, file_) == floats);
  if (!ok || std::fflush(file_) != 0) {
    *error = "write failed (disk full?): " + path_;
    return false;
  }
  edge->stored_at = offset;
  bytes_written_ += sizeof(h) + floats * sizeof(float);
  return true;
}

bool EdgeStore::Load(Edge* edge, std::string* error) {
  if (edge->points_resident) return true;
  if (file_ == nullptr || edge->stored_at < 0) {
    *error = "edge points are not stored";
    return false;
  }
  RecordHeader h{};
  if (std::fseek(file_, static_cast<long>(edge->stored_at), SEEK_SET) != 0 ||
      std::fread(&h, sizeof(h), 1, file_) != 1 || h.magic != kMagic || h.src != edge->src || h.tgt != edge->tgt ||
      h.n > kMaxPoints || h.n_holdout > kMaxPoints) {
    *error = "edges.bin: bad record at " + std::to_string(edge->stored_at);
    return false;
  }
  // Read straight into the edge's block; a record that does not verify leaves the edge without points.
  const size_t floats = 4 * (static_cast<size_t>(h.n) + h.n_holdout);
  float* payload = edge->points.Reset(h.n, h.n_holdout);
  if ((floats != 0 && std::fread(payload, sizeof(float), floats, file_) != floats) ||
      Fnv1a(payload, floats * sizeof(float)) != h.checksum) {
    edge->points.Free();
    *error = "edges.bin: corrupt record at " + std::to_string(edge->stored_at);
    return false;
  }
  edge->points_resident = true;
  return true;
}

size_t EdgeStore::Release(Edge* edge) {
  if (!edge->points_resident || edge->stored_at < 0) return 0;
  const size_t bytes = PointBytes(*edge);
  edge->points.Free();
  edge->points_resident = false;
  return bytes;
}

size_t PointBytes(const Edge& edge) {
  return edge.points.bytes();
}

}  // namespace uavm
