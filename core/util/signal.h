#pragma once
// Signal<Args...>: a publisher's list of subscribers, each held by a Connection that disconnects itself when it goes
// (libcamera's model): neither side's lifetime depends on the other's or on declaration order. A subscriber that goes
// first is never called again; a signal that goes first leaves its connections empty. Thread-safe: Emit() may run on
// a worker while a connection is dropped on another thread, and Disconnect() returns only once no call of that slot
// is running (a slot may disconnect itself).
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

namespace uavm {

class Connection {
 public:
  Connection() = default;
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;
  Connection(Connection&& other) noexcept : disconnect_(std::exchange(other.disconnect_, {})) {}
  Connection& operator=(Connection&& other) noexcept {
    if (this != &other) {
      Disconnect();
      disconnect_ = std::exchange(other.disconnect_, {});
    }
    return *this;
  }
  ~Connection() { Disconnect(); }

  void Disconnect() {
    if (disconnect_) std::exchange(disconnect_, {})();
  }
  [[nodiscard]] bool connected() const { return static_cast<bool>(disconnect_); }

 private:
  template <typename... Args>
  friend class Signal;
  explicit Connection(std::function<void()> disconnect) : disconnect_(std::move(disconnect)) {}

  std::function<void()> disconnect_;
};

template <typename... Args>
class Signal {
 public:
  using Slot = std::function<void(Args...)>;

  Signal() = default;
  Signal(const Signal&) = delete;
  Signal& operator=(const Signal&) = delete;

  // The slot is called by every Emit() until the returned connection is dropped or disconnected.
  [[nodiscard]] Connection Connect(Slot slot) {
    std::lock_guard lock(state_->mutex);
    const uint64_t key = ++state_->next_key;
    state_->slots.emplace_back(key, std::move(slot));
    std::weak_ptr<State> weak = state_;
    return Connection([weak, key] {
      if (auto state = weak.lock()) {
        std::lock_guard lock(state->mutex);
        auto& slots = state->slots;
        for (auto it = slots.begin(); it != slots.end(); ++it)
          if (it->first == key) {
            slots.erase(it);
            break;
          }
      }
    });
  }

  void Emit(Args... args) const {
    // Held by the emission: a slot may destroy the signal's owner.
    const std::shared_ptr<State> state = state_;
    std::lock_guard lock(state->mutex);
    // The slots connected when the emission starts, each looked up again before its call (an earlier one may have
    // disconnected it) and called through a copy (a slot may disconnect itself).
    std::vector<uint64_t> keys;
    keys.reserve(state->slots.size());
    for (const auto& entry : state->slots) keys.push_back(entry.first);
    for (const uint64_t key : keys)
      for (const auto& [k, slot] : state->slots)
        if (k == key) {
          const Slot call = slot;
          call(args...);
          break;
        }
  }

  [[nodiscard]] bool empty() const {
    std::lock_guard lock(state_->mutex);
    return state_->slots.empty();
  }

 private:
  struct State {
    mutable std::recursive_mutex mutex;
    uint64_t next_key = 0;
    std::vector<std::pair<uint64_t, Slot>> slots;
  };
  std::shared_ptr<State> state_ = std::make_shared<State>();
};

}  // namespace uavm
