#!/usr/bin/env bash
# The full tier: everything scripts/test.sh (the CI tier) runs, then
#   - the rest of the suite under qemu-aarch64 (every end-to-end test, at tests/test_env.h's emulated settings);
#   - the whole suite built with AddressSanitizer + UndefinedBehaviorSanitizer (scripts/test_asan.sh);
#   - every fuzzer for 120 s (UAVM_LONG_FUZZ_SECONDS) instead of 20000 executions.
# Run before a release, and for any change to what only these cover (memory handling, the aarch64 build, parsers).
# Same step table and time guard as the CI tier (scripts/ci_times.sh).
set -euo pipefail
source "$(dirname "$0")/ci_steps.sh"
export UAVM_FUNCTION_SIZE_ALL=1  # the function-size lint over every source, not only what changed
ci_tier
full_extras
