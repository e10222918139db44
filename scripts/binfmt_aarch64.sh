#!/usr/bin/env bash
# Registers qemu-aarch64 with the kernel's binfmt_misc (idempotent, needs root), so that an aarch64 program that a test
# starts itself (std::system, execv) runs under emulation like the test does. Debian's qemu-user-binfmt would do this
# through systemd-binfmt; CI machines and containers often run without systemd, hence this script.
# Prints "registered" or "already registered"; exits 1 with a reason when it cannot.
set -euo pipefail
QEMU=$(command -v qemu-aarch64 || true)
[ -n "$QEMU" ] || { echo "binfmt_aarch64: qemu-aarch64 not installed (apt-get install qemu-user)" >&2; exit 1; }
DIR=/proc/sys/fs/binfmt_misc
if [ ! -e "$DIR/register" ]; then
  mount -t binfmt_misc binfmt_misc "$DIR" 2>/dev/null ||
    { echo "binfmt_aarch64: cannot mount binfmt_misc (not root, or no permission in this container)" >&2; exit 1; }
fi
if [ -e "$DIR/qemu-aarch64" ]; then
  echo "already registered"
  exit 0
fi
# ELF64, little-endian, e_machine = 0xb7 (AArch64); mask as in Debian's qemu binfmt definitions.
MAGIC='\x7fELF\x02\x01\x01\x00\x00\x00\x00\x00\x00\x00\x00\x00\x02\x00\xb7\x00'
MASK='\xff\xff\xff\xff\xff\xff\xff\x00\xff\xff\xff\xff\xff\xff\xff\xff\xfe\xff\xff\xff'
printf ':qemu-aarch64:M::%s:%s:%s:' "$MAGIC" "$MASK" "$QEMU" >"$DIR/register" ||
  { echo "binfmt_aarch64: the kernel refused the registration" >&2; exit 1; }
echo "registered"
