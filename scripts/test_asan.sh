#!/usr/bin/env bash
# The whole CTest suite built with AddressSanitizer + UndefinedBehaviorSanitizer (LeakSanitizer on), in build-asan/
# (or $UAVM_ASAN_BUILD_DIR). Any sanitizer report fails the test that triggered it. Called by scripts/test.sh.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_ASAN_BUILD_DIR:-$ROOT/build-asan}"
UAVM_BUILD_DIR="$BUILD_DIR" bash "$ROOT/scripts/build.sh" -DUAVM_SANITIZE=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo
# halt_on_error: a UBSan finding ends the process with an error, so the test fails instead of printing and passing.
# Leaks inside third-party libraries' one-time initialisation are suppressed by library name (scripts/lsan.supp).
export ASAN_OPTIONS="detect_leaks=1:halt_on_error=1:abort_on_error=0:strict_string_checks=1:detect_stack_use_after_return=0"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
export LSAN_OPTIONS="suppressions=$ROOT/scripts/lsan.supp:print_suppressions=0"
cd "$BUILD_DIR"
ctest --output-on-failure -j "$(nproc)" --timeout 1800
