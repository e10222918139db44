#!/usr/bin/env bash
# Set-up-free test run (and CI's, through .ci/run): installs what is missing, builds, then runs
#   1. the native suite (Release build, build/);
#   2. every libFuzzer target for a short run (clang, ASan + UBSan; scripts/fuzz.sh);
#   3. the aarch64 cross build: the arm64 package and the aarch64 program against the native one on a real flight
#      (scripts/test_aarch64.sh steps 1-4).
# Each step prints its wall time ("test.sh: <step> N s") so that a slow CI run shows where the time went.
#
# The whole suite under AddressSanitizer + UndefinedBehaviorSanitizer (scripts/test_asan.sh) is not part of this run:
# it is a third full build, and CI's run of 2026-11-22 with it spent 943 s in that suite alone and had used 65 min
# before the fuzzers started (CI's budget is ~50 min on 2 cores). The fuzzers above are built with both sanitizers;
# run scripts/test_asan.sh before a release and after changes to memory handling.
#
# The whole suite under qemu-aarch64 (scripts/test_aarch64.sh step 5) is not part of this run either. Measured
# 2026-11-22 on 2 cores with the emulation settings of tests/test_env.h except --min-features 0: 156 of 198 tests in
# 37 min (4280 s of test time; the 56 bad-input cases 1512 s, the kill-and-resume test 1159 s). Detecting each frame
# once (--min-features 0) halves SIFT's share (three frames: 18 s instead of 37 s), not yet measured on the whole
# suite; even so the suite would bring CI too close to its 90 min limit. Run it with `scripts/test_aarch64.sh`.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_BUILD_DIR:-$ROOT/build}"
T_START=$(date +%s)

step() {
  local name="$1" t0
  shift
  t0=$(date +%s)
  echo "test.sh: -- $name"
  "$@"
  echo "test.sh: $name $(($(date +%s) - t0)) s (total $(($(date +%s) - T_START)) s)"
}

native_suite() {
  cd "$BUILD_DIR" && ctest --output-on-failure -j "$(nproc)" --timeout 900
}

step "setup" bash "$ROOT/scripts/setup.sh" clang
step "native build" bash "$ROOT/scripts/build.sh"
step "native suite" native_suite
step "fuzzing" bash "$ROOT/scripts/fuzz.sh" --runs 20000
step "aarch64" env UAVM_AARCH64_SUITE=0 bash "$ROOT/scripts/test_aarch64.sh"
echo "test.sh: all steps passed in $(($(date +%s) - T_START)) s"
