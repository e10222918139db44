#include "core/graph/components.h"

#include <algorithm>

namespace uavm {

int Components::Add() {
  const int id = sets_.Add();
  members_.push_back({id});
  return id;
}

int Components::Unite(int a, int b) {
  const int ra = sets_.Find(a);
  const int rb = sets_.Find(b);
  if (ra == rb) return ra;
  const int root = sets_.Unite(ra, rb);
  std::vector<int>& into = members_[static_cast<size_t>(root)];
  std::vector<int>& from = members_[static_cast<size_t>(root == ra ? rb : ra)];
  const auto middle = static_cast<long>(into.size());
  const bool newer = from.front() > into.back();
  into.insert(into.end(), from.begin(), from.end());
  if (!newer) std::inplace_merge(into.begin(), into.begin() + middle, into.end());
  std::vector<int>().swap(from);  // a root no more: give its memory back
  return root;
}

const std::vector<int>& Components::MembersOf(int id) {
  return members_[static_cast<size_t>(sets_.Find(id))];
}

}  // namespace uavm
