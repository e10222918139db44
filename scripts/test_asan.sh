#!/usr/bin/env bash
# test_asan.sh [build|suite]...: the whole CTest suite built with AddressSanitizer + UndefinedBehaviorSanitizer
# (LeakSanitizer on), in build-asan/ (or $UAVM_ASAN_BUILD_DIR). Any sanitizer report fails the test that triggered it.
# Both stages when none is named; scripts/test_full.sh (the full tier) runs them as timed steps.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_ASAN_BUILD_DIR:-$ROOT/build-asan}"
LOG_DIR="${UAVM_CI_LOG_DIR:-$BUILD_DIR}"

stage_build() {
  UAVM_BUILD_DIR="$BUILD_DIR" bash "$ROOT/scripts/build.sh" -DUAVM_SANITIZE=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DUAVM_BUILD_BENCH=OFF
}

stage_suite() {
  # halt_on_error: a UBSan finding ends the process with an error, so the test fails instead of printing and passing.
  # Leaks inside third-party libraries' one-time initialisation are suppressed by library name (scripts/lsan.supp).
  export ASAN_OPTIONS="detect_leaks=1:halt_on_error=1:abort_on_error=0:strict_string_checks=1:detect_stack_use_after_return=0"
  export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
  export LSAN_OPTIONS="suppressions=$ROOT/scripts/lsan.supp:print_suppressions=0"
  mkdir -p "$LOG_DIR"
  (cd "$BUILD_DIR" && ctest --output-on-failure -j "$(nproc)" --timeout 1800) 2>&1 | tee "$LOG_DIR/ctest-asan.log"
}

stages=("$@")
[ ${#stages[@]} -eq 0 ] && stages=(build suite)
for s in "${stages[@]}"; do
  case "$s" in
    build) stage_build ;;
    suite) stage_suite ;;
    *) echo "test_asan.sh: unknown stage '$s' (build, suite)" >&2; exit 2 ;;
  esac
done
