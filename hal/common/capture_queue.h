#pragma once
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>

#include "hal/common/pixel_convert.h"

namespace uavm::hal {

// The pool a captured buffer comes from (a V4L2 mmap buffer set, a libcamera request set): allocated once when the
// stream starts; Return() gives a buffer back to the driver. The pool outlives every handle it issued.
class BufferPool {
 public:
  virtual ~BufferPool() = default;
  // Called exactly once per handle, from whichever thread releases it. Must not throw or block for long.
  virtual void Return(uint32_t slot, uint64_t generation) noexcept = 0;
};

// RAII handle on one filled capture buffer (rpicam-apps style): while it lives the driver cannot reuse the memory;
// destroying it (after conversion, or when the queue drops it) re-queues the buffer. Move-only.
class CapturedBuffer {
 public:
  CapturedBuffer() = default;
  // `pool` is borrowed.
  CapturedBuffer(BufferPool* pool, uint32_t slot, uint64_t generation, RawImage image, int64_t timestamp_ns,
                 uint64_t sequence)
      : pool_(pool),
        slot_(slot),
        generation_(generation),
        image_(image),
        timestamp_ns_(timestamp_ns),
        sequence_(sequence) {}
  CapturedBuffer(CapturedBuffer&& o) noexcept { *this = std::move(o); }
  CapturedBuffer& operator=(CapturedBuffer&& o) noexcept {
    if (this != &o) {
      Release();
      pool_ = o.pool_;
      slot_ = o.slot_;
      generation_ = o.generation_;
      image_ = o.image_;
      timestamp_ns_ = o.timestamp_ns_;
      sequence_ = o.sequence_;
      o.pool_ = nullptr;
    }
    return *this;
  }
  CapturedBuffer(const CapturedBuffer&) = delete;
  CapturedBuffer& operator=(const CapturedBuffer&) = delete;
  ~CapturedBuffer() { Release(); }

  void Release() noexcept {
    if (pool_ != nullptr) pool_->Return(slot_, generation_);
    pool_ = nullptr;
  }
  [[nodiscard]] bool valid() const { return pool_ != nullptr; }
  [[nodiscard]] const RawImage& image() const { return image_; }
  [[nodiscard]] int64_t timestamp_ns() const { return timestamp_ns_; }  // driver timestamp, CLOCK_MONOTONIC ns
  [[nodiscard]] uint64_t sequence() const { return sequence_; }         // driver frame counter

 private:
  BufferPool* pool_ = nullptr;
  uint32_t slot_ = 0;
  uint64_t generation_ = 0;
  RawImage image_;
  int64_t timestamp_ns_ = 0;
  uint64_t sequence_ = 0;
};

// Bounded queue of filled buffers between a camera's capture thread and the consumer. Push never blocks: when the
// queue is full the oldest buffer is dropped (its handle returns it to the driver at once) and counted. Its capacity
// must stay below the pool size so that the driver always keeps buffers to fill.
class CaptureQueue {
 public:
  explicit CaptureQueue(size_t capacity) : capacity_(capacity < 1 ? 1 : capacity) {}

  // Returns false (and releases the buffer) when the queue is closed.
  bool Push(CapturedBuffer buffer) {
    CapturedBuffer dropped;  // released after the lock: Return() may take the pool's own lock
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (closed_) return false;
      if (items_.size() >= capacity_) {
        dropped = std::move(items_.front());
        items_.pop_front();
        ++dropped_;
      }
      items_.push_back(std::move(buffer));
      ++pushed_;
      if (items_.size() > high_water_) high_water_ = items_.size();
    }
    cv_.notify_one();
    return true;
  }

  // Waits up to `timeout` for a buffer; nullopt on timeout or when closed and empty.
  std::optional<CapturedBuffer> Pop(std::chrono::milliseconds timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, timeout, [&] { return closed_ || !items_.empty(); });
    if (items_.empty()) return std::nullopt;
    CapturedBuffer b = std::move(items_.front());
    items_.pop_front();
    return b;
  }

  // Releases every queued buffer (counted as dropped); returns how many.
  size_t Clear() {
    std::deque<CapturedBuffer> old;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      old.swap(items_);
      dropped_ += old.size();
    }
    return old.size();
  }

  void Close() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    cv_.notify_all();
  }
  void Reopen() {
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = false;
  }

  [[nodiscard]] size_t capacity() const { return capacity_; }
  [[nodiscard]] uint64_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }
  [[nodiscard]] uint64_t pushed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return pushed_;
  }
  [[nodiscard]] size_t high_water() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return high_water_;
  }
  [[nodiscard]] size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }

 private:
  const size_t capacity_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<CapturedBuffer> items_;
  bool closed_ = false;
  uint64_t dropped_ = 0;
  uint64_t pushed_ = 0;
  size_t high_water_ = 0;
};

}  // namespace uavm::hal
