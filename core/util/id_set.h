#pragma once
#include <algorithm>
#include <cstddef>
#include <vector>

namespace uavm {

// A set of frame ids, which are dense (a flight's are 0..frames-1): a byte an id instead of a hash node (~40 bytes
// with its bucket). The end of a long flight holds several sets of its frames at once (the component, the map).
class IdSet {
 public:
  IdSet() = default;
  template <typename Range>
  explicit IdSet(const Range& ids) {
    int largest = -1;
    for (int id : ids) largest = std::max(largest, id);
    flags_.assign(static_cast<size_t>(largest + 1), 0);
    for (int id : ids) insert(id);
  }

  void insert(int id) {
    if (id < 0) return;
    const auto i = static_cast<size_t>(id);
    if (i >= flags_.size()) flags_.resize(i + 1, 0);
    size_ += flags_[i] == 0 ? 1 : 0;
    flags_[i] = 1;
  }
  [[nodiscard]] bool contains(int id) const {
    return id >= 0 && static_cast<size_t>(id) < flags_.size() && flags_[static_cast<size_t>(id)] != 0;
  }
  [[nodiscard]] size_t size() const { return size_; }
  [[nodiscard]] bool empty() const { return size_ == 0; }

 private:
  std::vector<char> flags_;
  size_t size_ = 0;
};

}  // namespace uavm
