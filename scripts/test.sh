#!/usr/bin/env bash
# Set-up-free test run, the CI tier (what .ci/run calls): installs what is missing, builds, then runs
#   1. the native suite (Release build, build/): every test, unit and end-to-end, the camera VM included;
#   2. every libFuzzer target for 20000 executions (clang, ASan + UBSan; scripts/fuzz.sh);
#   3. the aarch64 cross build (scripts/test_aarch64.sh): the arm64 package installed and verified, the aarch64
#      program against the native one on every frame of a real flight, and under qemu-aarch64
#      the tests labelled unit-aarch64-ci and e2e-aarch64-ci (tests/CMakeLists.txt: the code whose results can differ
#      between the architectures).
# The cold steps come first and cost nothing on a warm machine: packages, the arm64 sysroot, the camera VM's kernel.
# Each step prints its wall time; at the end scripts/ci_times.sh prints the step table against scripts/ci_times.tsv
# and the ten slowest tests, and fails the run when a step took more than 1.5x its recorded time.
#
# The full tier (scripts/test_full.sh) adds the rest of the suite under qemu-aarch64, the whole suite under
# AddressSanitizer + UndefinedBehaviorSanitizer and a longer fuzzing run: run it before a release and for any change
# that only those cover (README, "Tests").
set -euo pipefail
source "$(dirname "$0")/ci_steps.sh"
ci_tier
