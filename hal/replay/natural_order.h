#pragma once
#include <string>

namespace uavm::hal {

// "img2.jpg" < "img10.jpg": digit runs compare as numbers, everything else byte-wise.
[[nodiscard]] bool NaturalLess(const std::string& a, const std::string& b);

}  // namespace uavm::hal
