#!/usr/bin/env bash
# Set-up-free test run (and CI's, through .ci/run): installs what is missing, builds, then runs
#   1. the native suite (Release build, build/);
#   2. every libFuzzer target for a short run (clang, ASan + UBSan; scripts/fuzz.sh);
#   3. the aarch64 cross build (scripts/test_aarch64.sh): the arm64 package installed and verified, the aarch64
#      program against the native one on every frame of a real flight, then the whole suite under qemu-aarch64.
# Each step prints its wall time ("test.sh: <step> N s") so that a slow CI run shows where the time went.
#
# Under qemu SIFT runs ~40x slower than natively, so heavy tests do less there (tests/test_env.h: 320 px working
# copies, one SIFT pass, shorter flights, no web tiles; the bad-input corpus on two good frames; the kill-and-resume
# test at three kill points; the ground tool on half-resolution keypoints). No test is skipped.
#
# The whole suite under AddressSanitizer + UndefinedBehaviorSanitizer (scripts/test_asan.sh) is not part of this run:
# it is a third full build, and CI's run of 2026-11-22 with it spent 943 s in that suite alone (CI's budget is ~50 min
# on 2 cores). The fuzzers above are built with both sanitizers; run scripts/test_asan.sh before a release and after
# changes to memory handling.
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
step "aarch64" bash "$ROOT/scripts/test_aarch64.sh"
echo "test.sh: all steps passed in $(($(date +%s) - T_START)) s"
