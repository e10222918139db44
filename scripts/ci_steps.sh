# Sourced by scripts/test.sh (the CI tier) and scripts/test_full.sh (the full tier): the steps of each tier, timed.
# Each step's wall time goes to $CI_LOG_DIR/steps.tsv and is printed as it ends; when the run ends, passed or not,
# scripts/ci_times.sh prints the step table against the recorded times (scripts/ci_times.tsv) and the ten slowest
# tests, and fails the run when a step took more than 1.5x its recorded time.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${UAVM_BUILD_DIR:-$ROOT/build}"
CI_LOG_DIR="${UAVM_CI_LOG_DIR:-$ROOT/ci-logs}"
export UAVM_CI_LOG_DIR="$CI_LOG_DIR"  # test_aarch64.sh and test_asan.sh keep their ctest output there too
T_START=$(date +%s)
mkdir -p "$CI_LOG_DIR"
: >"$CI_LOG_DIR/steps.tsv"
rm -f "$CI_LOG_DIR"/ctest-*.log

# step NAME COMMAND...: runs COMMAND, records its wall time under NAME.
step() {
  local name="$1" t0 status=0
  shift
  t0=$(date +%s)
  echo "ci: -- $name"
  "$@" || status=$?
  printf '%s\t%d\t%d\n' "$name" "$(($(date +%s) - t0))" "$status" >>"$CI_LOG_DIR/steps.tsv"
  echo "ci: $name $(($(date +%s) - t0)) s (total $(($(date +%s) - T_START)) s)"
  if [ "$status" -ne 0 ]; then
    echo "ci: step '$name' failed (exit $status)" >&2
    exit "$status"
  fi
}

# On exit, passed or failed: the step table, the slowest tests and the time guard.
finish() {
  local status=$?
  local guard=0
  bash "$ROOT/scripts/ci_times.sh" "$CI_LOG_DIR" || guard=$?
  if [ "$status" -eq 0 ] && [ "$guard" -ne 0 ]; then status=$guard; fi
  [ "$status" -eq 0 ] && echo "ci: all steps passed in $(($(date +%s) - T_START)) s"
  exit "$status"
}
trap finish EXIT

# What any tier installs: the build's packages, clang (fuzzers), the cross toolchain and qemu-user (aarch64), and
# what the camera VM needs; one apt call, so that a fresh machine pays apt's fixed costs once.
setup_all() {
  bash "$ROOT/scripts/setup.sh" clang crossbuild-essential-arm64 qemu-user mmdebstrap \
    qemu-system-x86 busybox-static kmod xz-utils
}

# The arm64 sysroot (its path, printed last, is for other callers).
sysroot_quiet() { bash "$ROOT/scripts/make_sysroot.sh" >/dev/null; }

# The camera VM's kernel and initramfs (cached outside the clone); 77 = cannot be prepared here, and the VM test then
# reports itself skipped with the reason.
vm_kernel() {
  local status=0
  bash "$ROOT/scripts/vm/prepare.sh" >/dev/null || status=$?
  [ "$status" -eq 77 ] && { echo "ci: camera VM cannot be prepared here (vm_camera_test will say skipped)"; return 0; }
  return "$status"
}

# ctest_logged NAME BUILD_DIR ARGS...: ctest in BUILD_DIR, its output also kept for the slowest-tests table.
ctest_logged() {
  local name="$1" dir="$2"
  shift 2
  (cd "$dir" && ctest --output-on-failure -j "$(nproc)" "$@") 2>&1 | tee "$CI_LOG_DIR/ctest-$name.log"
  return "${PIPESTATUS[0]}"
}

native_suite() {
  ctest_logged native "$BUILD_DIR" --timeout 900
}

# The CI tier fuzzes every parser but fuzz_config (the YAML options): its link needs the whole pipeline, 142 s more to
# build at -O0 on 2026-12-04 than the other five together (29 s); it runs in the full tier, 120 s like the others.
ci_fuzzing() { bash "$ROOT/scripts/fuzz.sh" --runs 20000 --quick-build --skip fuzz_config; }

# The CI tier (scripts/test.sh): the cold steps first (nothing to do on a warm machine), then the tests.
ci_tier() {
  step "setup" setup_all
  step "sysroot" sysroot_quiet
  step "vm kernel" vm_kernel
  step "native build" bash "$ROOT/scripts/build.sh"
  step "format" bash "$ROOT/scripts/lint.sh" --check
  step "layers" bash "$ROOT/scripts/lint.sh" --layers
  # What changed since the last full check (scripts/function_size_checked_at); the full tier checks every source.
  step "function size" bash "$ROOT/scripts/lint.sh" --function-size ${UAVM_FUNCTION_SIZE_ALL:+--all}
  step "native suite" native_suite
  step "accuracy gate" bash "$ROOT/scripts/accuracy_gate.sh"
  step "fuzzing" ci_fuzzing
  step "aarch64 build" bash "$ROOT/scripts/test_aarch64.sh" build ci
  step "aarch64 package" bash "$ROOT/scripts/test_aarch64.sh" package ci
  step "aarch64 parity" bash "$ROOT/scripts/test_aarch64.sh" parity
  step "aarch64 suite" bash "$ROOT/scripts/test_aarch64.sh" suite ci
}

# The full tier's additions (scripts/test_full.sh): the rest of the suite under qemu-aarch64, the whole suite under
# ASan + UBSan, and a longer fuzzing run.
# The memory test's long flight at the issue's length: 5000 frames under a hard cgroup limit of the budget + 16 MiB;
# and a 12 MP real flight under the same limit (UAVM_MEMORY_TEST_FULL_RES, default ../shared/data/caliterra/images:
# the test fails when the folder is missing).
long_flight_memory() {
  UAVM_MEMORY_TEST_FRAMES=5000 \
    UAVM_MEMORY_TEST_FULL_RES="${UAVM_MEMORY_TEST_FULL_RES:-$ROOT/../shared/data/caliterra/images}" \
    "$BUILD_DIR/tests/memory_limit_test" --gtest_filter='*LongSimulatedFlight*:*TwelveMegapixel*'
}

full_extras() {
  step "long flight memory" long_flight_memory
  step "aarch64 suite, e2e" bash "$ROOT/scripts/test_aarch64.sh" build package suite rest
  step "asan build" bash "$ROOT/scripts/test_asan.sh" build
  step "asan suite" bash "$ROOT/scripts/test_asan.sh" suite
  step "long fuzzing" bash "$ROOT/scripts/fuzz.sh" --seconds "${UAVM_LONG_FUZZ_SECONDS:-120}"
}
