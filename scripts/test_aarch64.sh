#!/usr/bin/env bash
# test_aarch64.sh [STAGE...]: the aarch64 cross build, tested on this x86 host under qemu-aarch64. Stages, in order
# (all of them when none is named; scripts/test.sh runs them one by one as timed steps):
#   build [ci]   the arm64 sysroot (scripts/make_sysroot.sh: made once, then reused from the cache) and the
#                aarch64-release preset built in build-aarch64/ (UAVM_AARCH64_BUILD_DIR); `build ci` builds only
#                what the CI tier runs (the target ci_tier_tests: the drone package's programs and the tests of
#                `suite ci`; not the ground tool or the tests only `suite rest` runs, which the full tier builds);
#   package [ci] the arm64 .debs installed into a scratch root, the unit verified, the programs run (tests/package/);
#                `package ci` the drone's package alone (uavmosaic: a CI-tier tree has no ground tool);
#   parity       the aarch64 uavmosaic-onboard on the bundled brighton_beach_small flight must register every frame,
#                with transforms within 0.5 px of the native build's (scripts/compare_sessions.py). Both runs use the
#                emulated suite's settings (320 px working copy, one SIFT pass: 2 min under qemu);
#                UAVM_AARCH64_PARITY=full runs the product's defaults instead (1000 px: 9.5 min under qemu on 2 cores;
#                18/18 frames, 0.0000 px on 2026-11-22). Needs the native build (scripts/build.sh);
#   suite [SEL]  CTest under emulation, with the reductions of tests/test_env.h. SEL: `ci` (the tests labelled
#                unit-aarch64-ci and e2e-aarch64-ci: the code whose results can differ between the architectures;
#                what CI runs), `rest` (every other test: the full tier adds them), `all` (default).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
NATIVE="${UAVM_BUILD_DIR:-$ROOT/build}"
BUILD="${UAVM_AARCH64_BUILD_DIR:-$ROOT/build-aarch64}"
LOG_DIR="${UAVM_CI_LOG_DIR:-$BUILD}"

sysroot() { bash "$ROOT/scripts/make_sysroot.sh" | tail -n 1; }

stage_build() {
  local selection="$1" sysroot_dir t0 stripped target=()
  sysroot_dir=$(sysroot)
  if [ ! -f "$BUILD/CMakeCache.txt" ]; then
    # The package installs what is built, not `all` first (a CI-tier tree has no end-to-end tests).
    cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DUAVM_BUILD_BENCH=OFF \
      -DCMAKE_SKIP_INSTALL_ALL_DEPENDENCY=ON \
      -DCMAKE_TOOLCHAIN_FILE="$ROOT/toolchains/aarch64-linux-gnu.cmake" -DUAVM_SYSROOT="$sysroot_dir" >/dev/null
  fi
  [ "$selection" = ci ] && target=(--target ci_tier_tests)
  t0=$(date +%s)
  cmake --build "$BUILD" -j "$(nproc)" "${target[@]}" >"$BUILD/aarch64-build.log" 2>&1 ||
    { tail -40 "$BUILD/aarch64-build.log"; exit 1; }
  echo "aarch64: build $(($(date +%s) - t0)) s"
  stripped=$(mktemp)
  local built=(firmware_app/uavmosaic-onboard tools/uavmosaic-sim tools/uavmosaic-eval)
  [ "$selection" = ci ] || built+=(ground_app/uavmosaic-ground)  # the CI tier does not build the ground tool
  for b in "${built[@]}"; do
    aarch64-linux-gnu-strip -o "$stripped" "$BUILD/$b"
    printf 'aarch64: %-28s %6d KiB (stripped %d KiB)\n' "$(basename "$b")" "$(($(stat -c %s "$BUILD/$b") / 1024))" \
      "$(($(stat -c %s "$stripped") / 1024))"
  done
  rm -f "$stripped"
}

stage_package() {
  local selection="$1" sysroot_dir components=  # empty: both packages
  [ "$selection" = ci ] && components=onboard
  sysroot_dir=$(sysroot)
  UAVM_PACKAGE_COMPONENTS="$components" bash "$ROOT/tests/package/package_test.sh" "$BUILD" qemu-aarch64 \
    -L "$sysroot_dir"
}

# End to end, native vs aarch64, on the same real flight.
stage_parity() {
  local sysroot_dir flight t0 frames registered
  sysroot_dir=$(sysroot)
  work=$(mktemp -d "${TMPDIR:-/tmp}/uavm_aarch64.XXXXXX")
  trap 'rm -rf "$work"' EXIT
  flight="replay:$ROOT/tests/data/brighton_beach_small/images"
  local parity_args=(--work-size 320 --min-features 0)  # tests/test_env.h's EmulationArgs
  [ "${UAVM_AARCH64_PARITY:-emulated}" = full ] && parity_args=()
  [ -x "$NATIVE/firmware_app/uavmosaic-onboard" ] || bash "$ROOT/scripts/build.sh"
  "$NATIVE/firmware_app/uavmosaic-onboard" --source "$flight" --out "$work/native" --no-tiff --log-level warn \
    "${parity_args[@]}"
  t0=$(date +%s)
  qemu-aarch64 -L "$sysroot_dir" "$BUILD/firmware_app/uavmosaic-onboard" --source "$flight" --out "$work/aarch64" \
    --no-tiff --log-level warn "${parity_args[@]}"
  echo "aarch64: brighton_beach_small under qemu-aarch64 (${parity_args[*]:-defaults}): $(($(date +%s) - t0)) s"
  python3 "$ROOT/scripts/compare_sessions.py" "$work/native" "$work/aarch64" --max-px 0.5
  frames=$(ls "$ROOT/tests/data/brighton_beach_small/images" | grep -ci '\.jpg$')
  registered=$(awk -F, 'NR > 1 && $3 == 1' "$work/aarch64/transforms.csv" | wc -l)
  echo "aarch64: $registered / $frames frames registered"
  [ "$registered" -eq "$frames" ] || { echo "aarch64: not every frame registered" >&2; exit 1; }
}

# Each test under qemu-aarch64 (CMAKE_CROSSCOMPILING_EMULATOR); the programs tests start themselves run through
# binfmt_misc. UAVM_EMULATED=1 (set by the toolchain's emulator command) gives heavy tests less to do
# (tests/test_env.h). Labels: tests/CMakeLists.txt. package_test is the package stage above, not run twice.
stage_suite() {
  local selection="${1:-all}" labels=() t0 status=0
  case "$selection" in
    ci) labels=(-L 'aarch64-ci$') ;;
    rest) labels=(-LE 'aarch64-ci$') ;;
    all) labels=() ;;
    *) echo "test_aarch64.sh: suite ci|rest|all, not '$selection'" >&2; exit 2 ;;
  esac
  QEMU_LD_PREFIX=$(sysroot)
  export QEMU_LD_PREFIX  # for aarch64 programs that tests start themselves (binfmt_misc for qemu-aarch64)
  bash "$ROOT/scripts/binfmt_aarch64.sh"
  t0=$(date +%s)
  (cd "$BUILD" && ctest --output-on-failure -j "$(nproc)" --timeout 3600 "${labels[@]}" -E '^package_test$') 2>&1 |
    tee "$LOG_DIR/ctest-aarch64-$selection.log" || status=$?
  echo "aarch64: emulated suite ($selection) $(($(date +%s) - t0)) s"
  return "$status"
}

stages=("$@")
[ ${#stages[@]} -eq 0 ] && stages=(build package parity suite)
i=0
while [ $i -lt ${#stages[@]} ]; do
  stage="${stages[$i]}"
  # A stage's selection, when the next word is one it takes (build and package: ci; suite: ci, rest, all).
  selection=all
  case "$stage" in
    build | package) choices='^ci$' ;;
    suite) choices='^(ci|rest|all)$' ;;
    *) choices= ;;
  esac
  if [[ -n $choices && ${stages[$((i + 1))]:-} =~ $choices ]]; then
    i=$((i + 1))
    selection="${stages[$i]}"
  fi
  case "$stage" in
    build) stage_build "$selection" ;;
    package) stage_package "$selection" ;;
    parity) stage_parity ;;
    suite) stage_suite "$selection" ;;
    *) echo "test_aarch64.sh: unknown stage '$stage' (build [ci], package [ci], parity, suite [ci|rest|all])" >&2; exit 2 ;;
  esac
  i=$((i + 1))
done
