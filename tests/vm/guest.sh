#!/bin/sh
# Runs inside the camera test VM, chrooted into the host's / (scripts/vm/init.sh starts it). Argument: the
# camera_device_test binary, commas for spaces: "BINARY,RESULTS_DIR[,--gtest_filter=...]". Writes into RESULTS_DIR; exits non-zero when a
# test fails.
set -u
BIN="$1"
RESULTS="$2"
FILTER="${3:-}"  # a --gtest_filter=... for camera_device_test, or nothing
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
export HOME=/tmp TMPDIR=/tmp UAVM_VM_RESULTS="$RESULTS"
export LIBCAMERA_LOG_LEVELS='*:WARN'
# The ASan build's options travel in a file (the kernel command line cannot carry them).
[ -f "$RESULTS/sanitizer.env" ] && . "$RESULTS/sanitizer.env"
# The MAVLink peer of the georeferenced flight (vm_camera_test.sh installs it on the host: the guest has no network).
[ -f "$RESULTS/peer.env" ] && . "$RESULTS/peer.env"
# Loopback for the flight's MAVLink stream and live view (nothing configures the guest's network).
ip link set lo up 2>/dev/null || ifconfig lo up 2>/dev/null || echo "guest: cannot bring up lo"
cd /tmp
echo "guest: kernel $(uname -r), $(nproc) CPUs"
ls -l /dev/video* /dev/media* 2>&1
# libcamera lists only devices udev has initialised; no udevd runs here, so record them as udevd would.
mkdir -p /run/udev/data
for d in /sys/class/video4linux/* /sys/bus/media/devices/*; do
  [ -f "$d/dev" ] && echo "I:1" >"/run/udev/data/c$(cat "$d/dev")"
done
ONBOARD_DIR=$(dirname "$BIN")/../firmware_app
"$ONBOARD_DIR/uavmosaic-onboard" --list-cameras >"$RESULTS/list_cameras.txt" 2>"$RESULTS/list_cameras.err"
echo "guest: --list-cameras exit $?"
cat "$RESULTS/list_cameras.txt"
start=$(date +%s)
"$BIN" --gtest_output="xml:$RESULTS/camera_device_test.xml" $FILTER
rc=$?
echo "guest: camera_device_test exit $rc after $(($(date +%s) - start)) s"
exit $rc
