#pragma once

namespace uavm {

// Peak resident set size of this process in MiB (getrusage ru_maxrss).
[[nodiscard]] double PeakRssMiB();
// Current resident set size in MiB (/proc/self/statm); 0 when unavailable.
[[nodiscard]] double CurrentRssMiB();

}  // namespace uavm
