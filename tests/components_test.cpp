#include "core/graph/components.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "core/util/portable_random.h"

namespace uavm {
namespace {

// The reference: a label per frame, relabelled by a full scan on every union (what the incremental lists replace).
struct ScanComponents {
  std::vector<int> label;
  int Add() {
    label.push_back(static_cast<int>(label.size()));
    return label.back();
  }
  void Unite(int a, int b) {
    const int from = label[static_cast<size_t>(b)];
    const int to = label[static_cast<size_t>(a)];
    for (int& l : label)
      if (l == from) l = to;
  }
  std::vector<int> MembersOf(int id) const {
    std::vector<int> out;
    for (size_t i = 0; i < label.size(); ++i)
      if (label[i] == label[static_cast<size_t>(id)]) out.push_back(static_cast<int>(i));
    return out;
  }
};

TEST(ComponentsTest, AFrameJoiningAComponentIsAppended) {
  Components c;
  for (int i = 0; i < 4; ++i) EXPECT_EQ(c.Add(), i);
  c.Unite(0, 1);
  c.Unite(1, 2);
  EXPECT_EQ(c.MembersOf(2), (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(c.MembersOf(3), (std::vector<int>{3}));
  EXPECT_EQ(c.SizeOf(0), 3);
  EXPECT_EQ(c.Unite(0, 2), c.Find(1));  // already one component: nothing changes
  EXPECT_EQ(c.MembersOf(0).size(), 3u);
}

TEST(ComponentsTest, MergingInterleavedComponentsKeepsIdsAscending) {
  Components c;
  for (int i = 0; i < 8; ++i) c.Add();
  // Two strips registered apart (even and odd frames), joined late: the lists interleave.
  for (int i = 2; i < 8; i += 2) c.Unite(0, i);
  for (int i = 3; i < 8; i += 2) c.Unite(1, i);
  EXPECT_EQ(c.MembersOf(1), (std::vector<int>{1, 3, 5, 7}));
  c.Unite(7, 6);
  EXPECT_EQ(c.MembersOf(0), (std::vector<int>{0, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_EQ(c.SizeOf(5), 8);
}

TEST(ComponentsTest, AgreesWithAFullScanOnRandomFlights) {
  PortableRandom rng(20261123);
  for (int flight = 0; flight < 20; ++flight) {
    Components c;
    ScanComponents ref;
    for (int step = 0; step < 300; ++step) {
      const int n = static_cast<int>(ref.label.size());
      if (n < 2 || rng.Uniform(0.0, 1.0) < 0.4) {
        ASSERT_EQ(c.Add(), ref.Add());
        continue;
      }
      // Mostly the newest frame joins a recent one (a flight), sometimes two old components merge (a bridge).
      const bool bridge = rng.Uniform(0.0, 1.0) < 0.1;
      const int a = bridge ? static_cast<int>(rng.Uniform(0.0, n)) : n - 1;
      const int b = static_cast<int>(rng.Uniform(bridge ? 0.0 : std::max(0.0, n - 10.0), n));
      c.Unite(std::min(a, n - 1), std::min(b, n - 1));
      ref.Unite(std::min(a, n - 1), std::min(b, n - 1));
    }
    for (int id = 0; id < static_cast<int>(ref.label.size()); ++id) {
      ASSERT_EQ(c.MembersOf(id), ref.MembersOf(id)) << "flight " << flight << ", frame " << id;
      ASSERT_EQ(c.SizeOf(id), static_cast<int>(ref.MembersOf(id).size()));
    }
  }
}

}  // namespace
}  // namespace uavm
