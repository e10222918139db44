#!/usr/bin/env bash
# CTest: the camera back-ends on real kernel video devices. Boots a VM with Debian's own 6.1 kernel, vivid and an
# out-of-tree vimc (scripts/vm/prepare.sh builds and caches them outside the clone), and runs in it, chrooted into
# the host's /, camera_device_test (V4L2 on vivid in three pixel formats, drops, unplug/reconnect, libcamera on vimc,
# the onboard program with slow processing, a georeferenced flight with a MAVLink stream) and
# `uavmosaic-onboard --list-cameras`.
#   vm_camera_test.sh CAMERA_DEVICE_TEST UAVMOSAIC_ONBOARD OUT_DIR
# Exit 77 (skipped) with the reason when the VM cannot start; otherwise the tests' verdict.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
BIN="$(realpath "$1")"
ONBOARD="$(realpath "$2")"
OUT="$(realpath -m "$3")"
[ -x "$BIN" ] && [ -x "$ONBOARD" ] || { echo "vm_camera_test: binaries missing" >&2; exit 1; }
if [ "$(dirname "$BIN")/../firmware_app/uavmosaic-onboard" -ef "$ONBOARD" ]; then :; else
  echo "vm_camera_test: expected the onboard binary next to the test's build tree" >&2
  exit 1
fi
rm -rf "$OUT"
mkdir -p "$OUT"
# Sanitizer builds: ASan/UBSan options for the guest (LeakSanitizer included) as the host's suite uses them. The
# capture tests run under the sanitizers on the real devices; the onboard run on vivid does not: under ASan and the
# VM's emulated CPU its 50 frames took 226 s (3x the plain build) and ASan's shadow memory puts its RSS over the
# test's bound (517 MiB); the pipeline itself is covered by the host suite's sanitized e2e tests.
FILTER=""
if ldd "$BIN" 2>/dev/null | grep libasan >/dev/null; then  # not grep -q: with pipefail, ldd would get SIGPIPE
  echo "vm_camera_test: sanitizer build: Onboard.* (the onboard program on vivid) not run in the VM, see above"
  FILTER="--gtest_filter=-Onboard.*"
  {
    echo "export ASAN_OPTIONS='${ASAN_OPTIONS:-detect_leaks=1:halt_on_error=1}'"
    echo "export UBSAN_OPTIONS='${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}'"
    echo "export LSAN_OPTIONS='${LSAN_OPTIONS:-}'"
  } >"$OUT/sanitizer.env"
fi
# The georeferenced flight's MAVLink peer (node-mavlink, tests/telemetry/run_peer.sh): installed here (the guest has
# no network), used read-only from the host's cache in the guest. Without node/npm that test is skipped and says why.
tmp_top() { case "$1" in /tmp/*) p=${1#/tmp/}; echo "/tmp/${p%%/*}" ;; *) echo / ;; esac; }
if command -v node >/dev/null &&
  MODULES=$(bash "$ROOT/tests/telemetry/run_peer.sh" --install 2>"$OUT/peer_install.log"); then
  # The guest sees the host's /tmp only where init.sh binds it: the folders of the script and the results.
  case "$(tmp_top "$MODULES")" in
    / | "$(tmp_top "$ROOT")" | "$(tmp_top "$OUT")")
      printf "export UAVM_PEER_RUN='%s' UAVM_PEER_MODULES='%s'\n" "$ROOT/tests/telemetry/run_peer.sh" "$MODULES" \
        >"$OUT/peer.env" ;;
    *) echo "vm_camera_test: the npm cache $MODULES is in a /tmp folder the guest does not see: no MAVLink peer" ;;
  esac
else
  echo "vm_camera_test: node-mavlink not installable (node, npm, registry; $OUT/peer_install.log): no MAVLink peer"
fi
start=$(date +%s)
set +e
bash "$ROOT/scripts/vm/run.sh" "$OUT" "$ROOT/tests/vm/guest.sh" "$BIN,$OUT${FILTER:+,$FILTER}"
rc=$?
set -e
echo "---- guest.log ----"
cat "$OUT/guest.log" 2>/dev/null || true
echo "---- measured ----"
cat "$OUT/rates.txt" 2>/dev/null || true
echo "vm_camera_test: $(($(date +%s) - start)) s in all (prepare + boot + tests), guest exit $rc"
[ "$rc" = 77 ] && exit 77
[ "$rc" = 0 ] || exit "$rc"
# --list-cameras saw both back-ends' devices.
grep -q "vivid" "$OUT/list_cameras.txt" || { echo "FAIL: --list-cameras shows no vivid node" >&2; exit 1; }
if grep -q "^libcamera: not built" "$OUT/list_cameras.txt"; then
  echo "note: libcamera back-end not built: vimc not checked through --list-cameras"
else
  grep -q "vimc" "$OUT/list_cameras.txt" || { echo "FAIL: --list-cameras shows no vimc camera" >&2; exit 1; }
fi
echo "vm_camera_test: PASS"
