#include "core/session/feature_store.h"

#include <cstdint>
#include <cstdio>
#include <cstring>

namespace uavm {

namespace {
constexpr char kMagic[8] = {'U', 'A', 'V', 'M', 'F', 'E', 'A', '1'};
constexpr double kQuant = 512.0;  // RootSIFT components are in [0,1]; x512 saturating fits 8 bits well
}  // namespace

bool WriteFeatures(const std::string& path, const Features& f, std::string* error) {
  cv::Mat q;
  if (f.descriptors.type() == CV_8U)
    q = f.descriptors;
  else
    f.descriptors.convertTo(q, CV_8U, kQuant);
  const std::string tmp = path + ".tmp";
  FILE* fp = std::fopen(tmp.c_str(), "wb");
  if (fp == nullptr) {
    *error = "cannot write " + tmp;
    return false;
  }
  const uint32_t n = static_cast<uint32_t>(f.points.size());
  const uint32_t dims = static_cast<uint32_t>(q.cols);
  bool ok = std::fwrite(kMagic, 1, 8, fp) == 8 && std::fwrite(&n, 4, 1, fp) == 1 && std::fwrite(&dims, 4, 1, fp) == 1;
  if (n > 0) {
    ok = ok && std::fwrite(f.points.data(), sizeof(cv::Point2f), n, fp) == n;
    const cv::Mat c = q.isContinuous() ? q : q.clone();
    ok = ok && std::fwrite(c.data, 1, c.total(), fp) == c.total();
  }
  ok = (std::fclose(fp) == 0) && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    *error = "write failed (disk full?): " + path;
    return false;
  }
  return true;
}

bool ReadFeatures(const std::string& path, Features* f, std::string* error) {
  FILE* fp = std::fopen(path.c_str(), "rb");
  if (fp == nullptr) {
    *error = "cannot open " + path;
    return false;
  }
  char magic[8];
  uint32_t n = 0;
  uint32_t dims = 0;
  bool ok = std::fread(magic, 1, 8, fp) == 8 && std::memcmp(magic, kMagic, 8) == 0 && std::fread(&n, 4, 1, fp) == 1 &&
            std::fread(&dims, 4, 1, fp) == 1 && n <= (1u << 22) && dims <= 1024;
  // The counts must match the file's size before anything is allocated: a corrupt header would otherwise ask for
  // up to 4 GiB.
  const uint64_t expected = 16 + static_cast<uint64_t>(n) * (sizeof(cv::Point2f) + dims);
  ok = ok && std::fseek(fp, 0, SEEK_END) == 0 && static_cast<uint64_t>(std::ftell(fp)) == expected &&
       std::fseek(fp, 16, SEEK_SET) == 0;
  if (ok) {
    f->points.resize(n);
    f->descriptors.create(static_cast<int>(n), static_cast<int>(dims), CV_8U);
    ok = (n == 0 || std::fread(f->points.data(), sizeof(cv::Point2f), n, fp) == n) &&
         (n == 0 || std::fread(f->descriptors.data, 1, f->descriptors.total(), fp) == f->descriptors.total());
  }
  std::fclose(fp);
  if (!ok) *error = "corrupt feature file " + path;
  return ok;
}

FeatureStore::FeatureStore(std::string dir, size_t max_bytes) : dir_(std::move(dir)), max_bytes_(max_bytes) {}

std::string FeatureStore::PathOf(int id) const {
  char name[32];
  std::snprintf(name, sizeof(name), "/%06d.bin", id);
  return dir_ + name;
}

namespace {
// What the store keeps of a frame's features: its own copy, descriptors quantised to 8 bits.
std::shared_ptr<Features> QuantizedCopy(const Features& features) {
  auto q = std::make_shared<Features>();
  q->points = features.points;
  if (features.descriptors.type() == CV_8U)
    q->descriptors = features.descriptors.clone();
  else
    features.descriptors.convertTo(q->descriptors, CV_8U, kQuant);
  q->contrast_threshold_used = features.contrast_threshold_used;
  return q;
}
}  // namespace

bool FeatureStore::Put(int id, const Features& features, std::string* error) {
  auto q = QuantizedCopy(features);
  if (!WriteFeatures(PathOf(id), *q, error)) return false;
  Insert(id, std::move(q));
  return true;
}

void FeatureStore::Adopt(int id, const Features& features) {
  Insert(id, QuantizedCopy(features));
}

bool FeatureStore::Load(int id, Features* features, std::string* error) const {
  return ReadFeatures(PathOf(id), features, error);
}

void FeatureStore::Insert(int id, std::shared_ptr<const Features> f) {
  const size_t bytes = f->MemoryBytes();
  while (!lru_.empty() && used_ + bytes > max_bytes_) {
    auto victim = entries_.find(lru_.back());
    used_ -= victim->second.features->MemoryBytes();
    entries_.erase(victim);
    lru_.pop_back();
    ++evictions_;
  }
  lru_.push_front(id);
  entries_[id] = Entry{std::move(f), lru_.begin()};
  used_ += bytes;
}

std::shared_ptr<const Features> FeatureStore::Get(int id) {
  auto it = entries_.find(id);
  if (it != entries_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second.pos);
    return it->second.features;
  }
  auto f = std::make_shared<Features>();
  std::string err;
  if (!ReadFeatures(PathOf(id), f.get(), &err)) return nullptr;
  ++disk_loads_;
  Insert(id, f);
  return f;
}

}  // namespace uavm
