#pragma once
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <optional>

namespace uavm {

// Fixed-capacity queue between capture and processing. A live camera must never block, so it drops the oldest
// item (kDropOldest) and counts it; a file replay applies back-pressure instead (kBlock): nothing is lost.
template <typename T>
class BoundedQueue {
 public:
  enum class Policy { kBlock, kDropOldest };

  BoundedQueue(size_t capacity, Policy policy) : capacity_(capacity < 1 ? 1 : capacity), policy_(policy) {}

  // Returns false when the queue was closed.
  bool Push(T item) {
    std::unique_lock<std::mutex> lock(mutex_);
    if (policy_ == Policy::kBlock) {
      not_full_.wait(lock, [&] { return closed_ || items_.size() < capacity_; });
    } else if (items_.size() >= capacity_) {
      items_.pop_front();
      ++dropped_;
    }
    if (closed_) return false;
    items_.push_back(std::move(item));
    high_water_ = items_.size() > high_water_ ? items_.size() : high_water_;
    not_empty_.notify_one();
    return true;
  }

  // Blocks until an item arrives; nullopt once closed and drained.
  std::optional<T> Pop() {
    std::unique_lock<std::mutex> lock(mutex_);
    not_empty_.wait(lock, [&] { return closed_ || !items_.empty(); });
    if (items_.empty()) return std::nullopt;
    T item = std::move(items_.front());
    items_.pop_front();
    not_full_.notify_one();
    return item;
  }

  void Close() {
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = true;
    not_empty_.notify_all();
    not_full_.notify_all();
  }

  [[nodiscard]] size_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }
  [[nodiscard]] size_t high_water() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return high_water_;
  }
  [[nodiscard]] size_t capacity() const { return capacity_; }

 private:
  const size_t capacity_;
  const Policy policy_;
  mutable std::mutex mutex_;
  std::condition_variable not_empty_;
  std::condition_variable not_full_;
  std::deque<T> items_;
  bool closed_ = false;
  size_t dropped_ = 0;
  size_t high_water_ = 0;
};

}  // namespace uavm
