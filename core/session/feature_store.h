#pragma once
#include <list>
#include <memory>
#include <string>
#include <unordered_map>

#include "core/features/sift.h"

namespace uavm {

// Features of every frame: written once to the session (features/NNNNNN.bin, 8-bit descriptors), kept in memory in
// a byte-bounded LRU. A miss reloads from disk, so a revisit many minutes later still finds the old frame's features.
class FeatureStore {
 public:
  FeatureStore(std::string dir, size_t max_bytes);
  // Stores (descriptors quantised to 8 bits). Returns false when the file cannot be written.
  [[nodiscard]] bool Put(int id, const Features& features, std::string* error);
  // Takes in a frame whose file is already in the session (a resumed run): cached, not rewritten.
  void Adopt(int id, const Features& features);
  // Reads a stored frame's features (8-bit descriptors). False when missing or corrupt.
  [[nodiscard]] bool Load(int id, Features* features, std::string* error) const;
  // nullptr when the frame was never stored or its file is unreadable.
  [[nodiscard]] std::shared_ptr<const Features> Get(int id);
  [[nodiscard]] size_t resident_bytes() const { return used_; }
  [[nodiscard]] size_t disk_loads() const { return disk_loads_; }
  [[nodiscard]] size_t evictions() const { return evictions_; }
  // Drops every resident entry (the files stay): the end of the flight needs the memory for other things.
  void Clear() {
    entries_.clear();
    lru_.clear();
    used_ = 0;
  }

 private:
  void Insert(int id, std::shared_ptr<const Features> f);
  [[nodiscard]] std::string PathOf(int id) const;

  std::string dir_;
  size_t max_bytes_;
  size_t used_ = 0;
  size_t disk_loads_ = 0;
  size_t evictions_ = 0;
  std::list<int> lru_;
  struct Entry {
    std::shared_ptr<const Features> features;
    std::list<int>::iterator pos;
  };
  std::unordered_map<int, Entry> entries_;
};

[[nodiscard]] bool WriteFeatures(const std::string& path, const Features& features, std::string* error);
[[nodiscard]] bool ReadFeatures(const std::string& path, Features* features, std::string* error);

}  // namespace uavm
