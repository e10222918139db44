#!/usr/bin/env bash
# Prepares (once) what the camera VM test boots: Debian's own 6.1 kernel, its vivid module, a vimc module built out of
# tree from Debian's linux-source-6.1 (Debian does not ship vimc), and a busybox initramfs that loads them.
# Everything goes into a cache directory outside the clone, keyed by the kernel's ABI name, and is reused when present:
#   ${UAVM_CACHE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/uavmosaic}/vm/<kernel version>/{vmlinuz,initrd.img,READY}
# Prints the ready directory on stdout (last line). Exit 77 with a reason on stderr when it cannot be prepared.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
CACHE_BASE="${UAVM_CACHE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/uavmosaic}/vm"
log() { echo "vm-prepare: $*" >&2; }
skip() { echo "vm-prepare: SKIP: $*" >&2; exit 77; }

# Host tools: qemu (TCG), busybox (the guest's userland), kmod (dependency resolution), xz (modules are .ko.xz),
# a compiler for the vimc module (build-essential is already a build dependency).
if ! bash "$ROOT/scripts/setup.sh" qemu-system-x86 busybox-static kmod xz-utils >&2; then
  skip "cannot install qemu-system-x86 busybox-static kmod xz-utils (no root or no apt)"
fi
mkdir -p "$CACHE_BASE" || skip "cannot create cache directory $CACHE_BASE"
exec 9>"$CACHE_BASE/.lock"
flock 9  # two test runs (release and ASan builds) share one cache

# Which kernel: the one linux-image-amd64 points at now; when apt knows none (offline), the newest cached one.
kernel_abi() { apt-cache depends linux-image-amd64 2>/dev/null | sed -n 's/.*Depends: linux-image-\(6\.1\.[^ ]*-amd64\)$/\1/p' | head -1; }
KVER="$(kernel_abi || true)"
if [ -z "$KVER" ] && [ "$(id -u)" = 0 ]; then
  apt-get update -qq >&2 || true  # a fresh machine whose package lists were never fetched
  KVER="$(kernel_abi || true)"
fi
if [ -z "$KVER" ] || [ ! -f "$CACHE_BASE/$KVER/READY" ]; then
  newest=$(ls -1 "$CACHE_BASE" 2>/dev/null | grep -E '^6\.1\.' | while read -r d; do
    [ -f "$CACHE_BASE/$d/READY" ] && echo "$d"; done | sort -V | tail -1 || true)
  if [ -n "$newest" ] && { [ -z "$KVER" ] || [ "${UAVM_VM_OFFLINE:-0}" = 1 ]; }; then KVER="$newest"; fi
fi
[ -n "$KVER" ] || skip "apt knows no linux-image-amd64 (6.1) and nothing is cached in $CACHE_BASE"
OUT="$CACHE_BASE/$KVER"
# The initramfs is packed from the cached tree plus scripts/vm/init.sh; repacked (1 s) when init.sh changed.
pack_initrd() {
  cp "$ROOT/scripts/vm/init.sh" "$OUT/initrd-tree/init"
  chmod +x "$OUT/initrd-tree/init"
  (cd "$OUT/initrd-tree" && find . | busybox cpio -o -H newc 2>/dev/null | gzip -1 >"$OUT/initrd.img.tmp")
  mv "$OUT/initrd.img.tmp" "$OUT/initrd.img"
  sha256sum "$ROOT/scripts/vm/init.sh" | cut -d' ' -f1 >"$OUT/init.sha256"
}
if [ -f "$OUT/READY" ]; then
  if [ "$(cat "$OUT/init.sha256" 2>/dev/null)" != "$(sha256sum "$ROOT/scripts/vm/init.sh" | cut -d' ' -f1)" ]; then
    log "init.sh changed: repacking the initramfs"
    pack_initrd
  fi
  log "cached: $OUT"
  echo "$OUT"
  exit 0
fi

log "preparing kernel $KVER into $OUT (cold cache: downloads ~150 MB, builds vimc)"
start=$(date +%s)
WORK="$CACHE_BASE/.work-$KVER"
rm -rf "$WORK" "$OUT"
mkdir -p "$WORK/debs" "$WORK/root"
cd "$WORK/debs"
KBUILD=$(apt-cache depends "linux-headers-$KVER" 2>/dev/null | sed -n 's/.*Depends: \(linux-kbuild-[^ ]*\)$/\1/p' | head -1)
COMMON=$(apt-cache depends "linux-headers-$KVER" 2>/dev/null | sed -n 's/.*Depends: \(linux-headers-[^ ]*-common\)$/\1/p' | head -1)
[ -n "$KBUILD" ] && [ -n "$COMMON" ] || skip "apt knows no linux-headers-$KVER dependencies"
for attempt in 1 2; do
  if apt-get download "linux-image-$KVER" "linux-headers-$KVER" "$COMMON" "$KBUILD" linux-source-6.1 >&2; then break; fi
  [ "$attempt" = 2 ] && skip "apt-get download of the kernel packages failed (no network?)"
  apt-get update -qq >&2 || true
done
for d in *.deb; do dpkg -x "$d" "$WORK/root"; done
MODDIR="$WORK/root/lib/modules/$KVER"
[ -f "$WORK/root/boot/vmlinuz-$KVER" ] || skip "linux-image-$KVER has no /boot/vmlinuz-$KVER"

# vimc, out of tree, against the headers of exactly this kernel.
log "building vimc.ko"
tar -xJf "$WORK/root/usr/src/linux-source-6.1.tar.xz" -C "$WORK" linux-source-6.1/drivers/media/test-drivers/vimc
VIMC="$WORK/linux-source-6.1/drivers/media/test-drivers/vimc"
# The headers' Makefile includes the -common one by its installed path: point it at the unpacked copy.
sed -i "s#/usr/src/#$WORK/root/usr/src/#" "$WORK/root/usr/src/linux-headers-$KVER/Makefile"
make -s -C "$WORK/root/usr/src/linux-headers-$KVER" M="$VIMC" CONFIG_VIDEO_VIMC=m -j2 modules >&2 ||
  skip "building vimc.ko against linux-headers-$KVER failed"
mkdir -p "$MODDIR/extra"
cp "$VIMC/vimc.ko" "$MODDIR/extra/vimc.ko"
depmod -b "$WORK/root" "$KVER"

# The initramfs: busybox, the modules (dependencies first, decompressed: busybox insmod has no xz), /init.
INITRD="$WORK/initrd"
mkdir -p "$INITRD"/{bin,dev,proc,sys,host,mnt,modules}
cp /bin/busybox "$INITRD/bin/busybox"
for m in virtio_pci 9pnet_virtio 9p vivid vimc; do
  modprobe -d "$WORK/root" -S "$KVER" --show-depends "$m" | awk '$1 == "insmod" {print $2}'
done | awk '!seen[$0]++' >"$WORK/order.txt"
: >"$INITRD/modules/order"
while read -r path; do
  rel="${path#"$WORK/root"}"
  name=$(basename "$rel")
  name="${name%.xz}"
  case "$rel" in
    *.xz) xz -dc "$WORK/root$rel" >"$INITRD/modules/$name" ;;
    *) cp "$WORK/root$rel" "$INITRD/modules/$name" ;;
  esac
  echo "$name" >>"$INITRD/modules/order"
done <"$WORK/order.txt"
mkdir -p "$OUT"
cp "$WORK/root/boot/vmlinuz-$KVER" "$OUT/vmlinuz"
mv "$INITRD" "$OUT/initrd-tree"
pack_initrd
rm -rf "$WORK"
echo "$KVER" >"$OUT/READY"
log "ready in $(($(date +%s) - start)) s: $OUT"
echo "$OUT"
