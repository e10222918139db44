#include "core/util/id_set.h"

#include <gtest/gtest.h>

#include <random>
#include <set>
#include <vector>

namespace uavm {
namespace {

// Against std::set on random ids, inserted in any order and repeated: the same membership and size.
TEST(IdSetTest, AgreesWithStdSet) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> id(0, 499);
  std::vector<int> ids;
  for (int i = 0; i < 300; ++i) ids.push_back(id(rng));
  const IdSet from_range(ids);
  IdSet inserted;
  std::set<int> reference;
  for (int v : ids) {
    inserted.insert(v);
    reference.insert(v);
  }
  EXPECT_EQ(from_range.size(), reference.size());
  EXPECT_EQ(inserted.size(), reference.size());
  for (int v = -3; v < 600; ++v) {
    EXPECT_EQ(from_range.contains(v), reference.count(v) != 0) << v;
    EXPECT_EQ(inserted.contains(v), reference.count(v) != 0) << v;
  }
}

TEST(IdSetTest, EmptyAndNegativeIds) {
  IdSet s;
  EXPECT_TRUE(s.empty());
  EXPECT_FALSE(s.contains(0));
  s.insert(-1);  // not a frame id: ignored
  EXPECT_TRUE(s.empty());
  s.insert(0);
  s.insert(0);
  EXPECT_EQ(s.size(), 1U);
  EXPECT_TRUE(s.contains(0));
  EXPECT_FALSE(s.contains(1));
}

}  // namespace
}  // namespace uavm
