#!/usr/bin/env bash
# Set-up-free test run: installs what is missing, builds, then runs the whole CTest suite.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_BUILD_DIR:-$ROOT/build}"
bash "$ROOT/scripts/build.sh"
cd "$BUILD_DIR"
ctest --output-on-failure -j "$(nproc)" --timeout 900

# ---- sanitizers: the whole suite again, built with ASan + UBSan, LeakSanitizer on (build-asan/) -------------------
bash "$ROOT/scripts/test_asan.sh"
# ---- end of sanitizers ---------------------------------------------------------------------------------------------

# ---- fuzzing: a short run of every libFuzzer target (fuzz/, build-fuzz/; the long run is bench/fuzz.sh) ----------
# clang provides libFuzzer; installed when missing by the same helper. A crash fails the script.
bash "$ROOT/scripts/setup.sh" clang
bash "$ROOT/scripts/fuzz.sh" --runs 20000
# ---- end of fuzzing ----------------------------------------------------------------------------------------------

# ---- aarch64: the cross build (sysroot made once, cached in /var/cache/uavmosaic), the arm64 package, the aarch64
# program against the native one on a real flight (transforms within 0.5 px), and the whole suite under qemu-aarch64.
# The emulated suite (test_aarch64.sh step 5) is left out of CI for now: at native test sizes it takes over two hours
# under qemu-user on 2 cores (measured 2026-11-22: 54 of 198 tests in 14 min, each end-to-end test 4-5 min). Run it
# with `scripts/test_aarch64.sh` (UAVM_AARCH64_SUITE=1, the default there).
UAVM_AARCH64_SUITE=0 bash "$ROOT/scripts/test_aarch64.sh"
# ---- end of aarch64 ------------------------------------------------------------------------------------------------
