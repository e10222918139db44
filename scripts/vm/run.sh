#!/usr/bin/env bash
# Boots the camera test VM (scripts/vm/prepare.sh makes and caches its kernel and initramfs) and runs a script of the
# host's inside it: the guest mounts the host's / read-only over virtio-9p and chroots into it, so host-built binaries
# run unchanged against the guest's /dev/video* (vivid, vimc). RESULTS_DIR is shared writable (guest.log, the
# script's own files). Exits with the guest script's status; 77 (CTest's skip) with the reason when no VM can run.
#   scripts/vm/run.sh RESULTS_DIR GUEST_SCRIPT [ARG]     (ARG: one word; commas become spaces in the guest)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
RESULTS="$(realpath -m "$1")"
SCRIPT="$(realpath "$2")"
ARG="${3:-}"
skip() { echo "vm: SKIP: $*" >&2; exit 77; }

KDIR=$(bash "$ROOT/scripts/vm/prepare.sh" | tail -1) || exit $?
command -v qemu-system-x86_64 >/dev/null || skip "qemu-system-x86_64 not installed"
case "$RESULTS$SCRIPT$ARG" in *" "*) skip "paths with spaces cannot go on the kernel command line" ;; esac
mkdir -p "$RESULTS"
rm -f "$RESULTS/guest_exit" "$RESULTS/guest.log"
# TCG, not KVM: /dev/kvm exists on CI machines but nested virtualisation cannot boot a stock kernel there.
# CPU model qemu64 (SSE3, no AVX): OpenCV then takes its SSE paths, which TCG runs 2-3x faster than the AVX2 ones
# of -cpu max (measured: 20 onboard frames 110 s vs killed at 150 s).
start_ms=$(($(date +%s%N) / 1000000))
set +e
timeout "${UAVM_VM_TIMEOUT:-600}" qemu-system-x86_64 -accel tcg,thread=multi -cpu "${UAVM_VM_CPU:-qemu64}" -smp 2 -m 2048 \
  -nographic -no-reboot -monitor none \
  -kernel "$KDIR/vmlinuz" -initrd "$KDIR/initrd.img" \
  -append "console=ttyS0 loglevel=3 panic=-1 uavm_script=$SCRIPT uavm_results=$RESULTS uavm_args=$ARG" \
  -virtfs local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap \
  -virtfs local,path="$RESULTS",mount_tag=results,security_model=none,multidevs=remap \
  </dev/null >"$RESULTS/console.log" 2>&1
qemu_rc=$?
set -e
elapsed_ms=$(($(date +%s%N) / 1000000 - start_ms))
elapsed="$((elapsed_ms / 1000)).$(printf %03d $((elapsed_ms % 1000)))"
echo "vm: qemu exited $qemu_rc after ${elapsed} s (console: $RESULTS/console.log)" >&2
guest=$(sed -n 's/.*UAVM_VM_EXIT=\([0-9]*\).*/\1/p' "$RESULTS/console.log" | tail -1)
if [ -z "$guest" ]; then
  tail -30 "$RESULTS/console.log" >&2
  if [ "$qemu_rc" = 124 ]; then
    echo "vm: the guest did not finish within ${UAVM_VM_TIMEOUT:-600} s" >&2
    exit 1
  fi
  skip "the VM did not boot to the test script (qemu exit $qemu_rc; console above)"
fi
case "$guest" in
  90) skip "the guest could not mount the host's / over virtio-9p" ;;
  91) skip "the guest could not mount the results share" ;;
esac
exit "$guest"
