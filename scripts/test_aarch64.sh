#!/usr/bin/env bash
# test_aarch64.sh: the aarch64 cross build, tested on this x86 host under qemu-aarch64.
#   1. the arm64 sysroot (scripts/make_sysroot.sh: made once, then reused from the cache);
#   2. the aarch64-release preset built in build-aarch64/ (UAVM_AARCH64_BUILD_DIR);
#   3. the arm64 .deb: installed into a scratch root, its unit verified, its program run (tests/package/);
#   4. end to end: the aarch64 uavmosaic-onboard on the bundled brighton_beach_small flight must register every frame,
#      with transforms within 0.5 px of the native build's (scripts/compare_sessions.py). Both runs use the emulated
#      suite's settings (320 px working copy, one SIFT pass: 2 min under qemu); UAVM_AARCH64_PARITY=full runs the
#      product's defaults instead (1000 px: 9.5 min under qemu on 2 cores; 18/18 frames, 0.0000 px on 2026-11-22);
#   5. the whole CTest suite under emulation, with the reductions of tests/test_env.h (UAVM_AARCH64_SUITE=0 leaves
#      it out).
# Needs the native build (scripts/build.sh) for step 4.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
NATIVE="${UAVM_BUILD_DIR:-$ROOT/build}"
BUILD="${UAVM_AARCH64_BUILD_DIR:-$ROOT/build-aarch64}"
t0=$(date +%s)
SYSROOT=$(bash "$ROOT/scripts/make_sysroot.sh" | tail -n 1)
export QEMU_LD_PREFIX="$SYSROOT"  # for aarch64 programs that tests start themselves (needs binfmt_misc for qemu-aarch64)

if [ ! -f "$BUILD/CMakeCache.txt" ]; then
  cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DUAVM_BUILD_BENCH=OFF \
    -DCMAKE_TOOLCHAIN_FILE="$ROOT/toolchains/aarch64-linux-gnu.cmake" -DUAVM_SYSROOT="$SYSROOT" >/dev/null
fi
t_build=$(date +%s)
cmake --build "$BUILD" -j "$(nproc)" >"$BUILD/aarch64-build.log" 2>&1 || { tail -40 "$BUILD/aarch64-build.log"; exit 1; }
echo "aarch64: build $(($(date +%s) - t_build)) s"
stripped=$(mktemp)
for b in firmware_app/uavmosaic-onboard ground_app/uavmosaic-ground tools/uavmosaic-sim tools/uavmosaic-eval; do
  aarch64-linux-gnu-strip -o "$stripped" "$BUILD/$b"
  printf 'aarch64: %-28s %6d KiB (stripped %d KiB)\n' "$(basename "$b")" "$(($(stat -c %s "$BUILD/$b") / 1024))" \
    "$(($(stat -c %s "$stripped") / 1024))"
done
rm -f "$stripped"

bash "$ROOT/tests/package/package_test.sh" "$BUILD" qemu-aarch64 -L "$SYSROOT"

# End to end, native vs aarch64, on the same real flight.
WORK=$(mktemp -d "${TMPDIR:-/tmp}/uavm_aarch64.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
FLIGHT="replay:$ROOT/tests/data/brighton_beach_small/images"
PARITY_ARGS=(--work-size 320 --min-features 0)  # tests/test_env.h's EmulationArgs
[ "${UAVM_AARCH64_PARITY:-emulated}" = full ] && PARITY_ARGS=()
[ -x "$NATIVE/firmware_app/uavmosaic-onboard" ] || bash "$ROOT/scripts/build.sh"
"$NATIVE/firmware_app/uavmosaic-onboard" --source "$FLIGHT" --out "$WORK/native" --no-tiff --log-level warn \
  "${PARITY_ARGS[@]}"
t_e2e=$(date +%s)
qemu-aarch64 -L "$SYSROOT" "$BUILD/firmware_app/uavmosaic-onboard" --source "$FLIGHT" --out "$WORK/aarch64" \
  --no-tiff --log-level warn "${PARITY_ARGS[@]}"
echo "aarch64: brighton_beach_small under qemu-aarch64 (${PARITY_ARGS[*]:-defaults}): $(($(date +%s) - t_e2e)) s"
python3 "$ROOT/scripts/compare_sessions.py" "$WORK/native" "$WORK/aarch64" --max-px 0.5
frames=$(ls "$ROOT/tests/data/brighton_beach_small/images" | grep -ci '\.jpg$')
registered=$(awk -F, 'NR > 1 && $3 == 1' "$WORK/aarch64/transforms.csv" | wc -l)
echo "aarch64: $registered / $frames frames registered"
[ "$registered" -eq "$frames" ] || { echo "aarch64: not every frame registered" >&2; exit 1; }

if [ "${UAVM_AARCH64_SUITE:-1}" = 1 ]; then
  # The whole suite, each test under qemu-aarch64 (CMAKE_CROSSCOMPILING_EMULATOR); the programs tests start
  # themselves run through binfmt_misc. UAVM_EMULATED=1 (set by the toolchain's emulator command) gives heavy tests
  # less to do (tests/test_env.h).
  bash "$ROOT/scripts/binfmt_aarch64.sh"
  t_suite=$(date +%s)
  (cd "$BUILD" && ctest --output-on-failure -j "$(nproc)" --timeout 3600)
  echo "aarch64: emulated suite $(($(date +%s) - t_suite)) s"
fi
echo "aarch64: all steps passed in $(($(date +%s) - t0)) s"
