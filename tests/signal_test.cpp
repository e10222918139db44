// Signal and Connection (core/util/signal.h): subscribers that disconnect themselves, whichever side goes first.
#include "core/util/signal.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <thread>

namespace uavm {
namespace {

TEST(SignalTest, EverySlotIsCalledUntilItsConnectionGoes) {
  Signal<int> signal;
  int a = 0, b = 0;
  Connection ca = signal.Connect([&](int v) { a += v; });
  {
    Connection cb = signal.Connect([&](int v) { b += v; });
    signal.Emit(2);
  }
  signal.Emit(3);
  EXPECT_EQ(a, 5);
  EXPECT_EQ(b, 2);
  ca.Disconnect();
  EXPECT_FALSE(ca.connected());
  signal.Emit(7);
  EXPECT_EQ(a, 5);
  EXPECT_TRUE(signal.empty());
}

TEST(SignalTest, AConnectionOutlivingItsSignalIsHarmless) {
  Connection c;
  {
    Signal<> signal;
    c = signal.Connect([] {});
    EXPECT_TRUE(c.connected());
  }
  c.Disconnect();  // the signal has gone: nothing to do, no crash
  EXPECT_FALSE(c.connected());
}

TEST(SignalTest, ASlotMayDisconnectItselfOrTheNextDuringAnEmission) {
  Signal<> signal;
  int first = 0, second = 0;
  Connection c2;
  Connection c1 = signal.Connect([&] {
    ++first;
    c1.Disconnect();
    c2.Disconnect();
  });
  c2 = signal.Connect([&] { ++second; });
  signal.Emit();
  signal.Emit();
  EXPECT_EQ(first, 1);
  EXPECT_EQ(second, 0);
}

TEST(SignalTest, DisconnectWaitsForASlotRunningOnAnotherThread) {
  Signal<> signal;
  std::atomic<bool> in_slot{false}, slot_done{false};
  auto c = std::make_unique<Connection>(signal.Connect([&] {
    in_slot = true;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    slot_done = true;
  }));
  std::thread worker([&] { signal.Emit(); });
  while (!in_slot) std::this_thread::yield();
  c.reset();  // returns only once the running call is over: the subscriber may go right after
  EXPECT_TRUE(slot_done);
  worker.join();
}

}  // namespace
}  // namespace uavm
