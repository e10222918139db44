#!/bin/busybox sh
# /init of the camera test VM's initramfs (scripts/vm/prepare.sh packs it; scripts/vm/run.sh boots it).
# Loads the modules (virtio 9p, vivid, vimc), mounts the host's / read-only and the results share writable, then runs
# the host-side guest script in a chroot of the host's / so that host-built binaries run unchanged. The script's exit
# status goes to the serial console as "UAVM_VM_EXIT=<n>" and into <results>/guest_exit; then the VM powers off.
# Parameters come from the kernel command line (the kernel hands unknown name=value words to init as environment):
#   uavm_script=PATH (host path of the guest script), uavm_results=PATH (host path of the writable share),
#   uavm_args=WORD (one argument for the script, commas for spaces).
/bin/busybox mkdir -p /proc /sys /dev /host /tmp
/bin/busybox mount -t proc proc /proc
/bin/busybox mount -t sysfs sysfs /sys
/bin/busybox mount -t devtmpfs devtmpfs /dev
bb=/bin/busybox
finish() {
  echo; echo "UAVM_VM_EXIT=$1"
  [ -d "/host$uavm_results" ] && echo "$1" >"/host$uavm_results/guest_exit"
  $bb sync
  $bb poweroff -f
}
for m in $($bb cat /modules/order); do
  opts=""
  # vivid: one instance with a video capture node and a video output node (the georeferenced flight loops pictures
  # through it); vimc after it, so vivid's capture is the first /dev/video node.
  [ "$m" = vivid.ko ] && opts="n_devs=1 node_types=0x101"
  $bb insmod "/modules/$m" $opts || echo "init: insmod $m failed"
done
$bb mount -t 9p -o trans=virtio,version=9p2000.L,msize=1048576,ro,cache=loose hostroot /host || finish 90
$bb mount -t devtmpfs devtmpfs /host/dev
$bb mount -t proc proc /host/proc
$bb mount -t sysfs sysfs /host/sys
# The guest needs a writable /tmp, but a checkout or build under the host's /tmp would then be hidden: keep the
# host's /tmp reachable at /mnt/hosttmp and bind the folders the test names back over the new tmpfs.
$bb mkdir -p /mnt/hosttmp
$bb mount -o bind /host/tmp /mnt/hosttmp
$bb mount -t tmpfs tmpfs /host/tmp
for p in "$uavm_script" "$uavm_results" $(echo "$uavm_args" | $bb tr ',' ' '); do
  case "$p" in
    /tmp/?*)
      top=${p#/tmp/}
      top=${top%%/*}
      if [ ! -d "/host/tmp/$top" ]; then
        $bb mkdir -p "/host/tmp/$top"
        $bb mount -o bind "/mnt/hosttmp/$top" "/host/tmp/$top" || echo "init: cannot bind /tmp/$top"
      fi
      ;;
  esac
done
$bb mount -t tmpfs tmpfs /host/run
$bb mount -t tmpfs tmpfs /host/var/tmp 2>/dev/null
# Last, so that none of the tmpfs above hides it (it may live under /tmp).
$bb mkdir -p "/host$uavm_results" 2>/dev/null
$bb mount -t 9p -o trans=virtio,version=9p2000.L,msize=1048576,cache=none results "/host$uavm_results" || finish 91
args=$(echo "$uavm_args" | $bb tr ',' ' ')
$bb chroot /host /bin/sh "$uavm_script" $args >"/host$uavm_results/guest.log" 2>&1
finish $?
