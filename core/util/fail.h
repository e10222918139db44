#pragma once
// The error convention's one step (README, "Error convention"): an operation that cannot go on writes its one-line
// reason to `error` (when the caller asked for one) and returns false.
#include <string>
#include <utility>

namespace uavm {

[[nodiscard]] inline bool Fail(std::string* error, std::string reason) {
  if (error != nullptr) *error = std::move(reason);
  return false;
}

}  // namespace uavm
