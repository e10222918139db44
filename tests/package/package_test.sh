#!/usr/bin/env bash
# package_test.sh BUILD_DIR [EMULATOR...]
#
# Builds the .debs of BUILD_DIR with CPack (uavmosaic, the drone's, and uavmosaic-ground; the drone's alone when
# UAVM_PACKAGE_COMPONENTS=onboard: a tree that did not build the ground tool), installs them into a scratch root with
# `dpkg --root` (maintainer scripts outside the chroot, DPKG_ROOT set), and checks: dpkg lists the package as installed with its files; the unit passes
# `systemd-analyze verify`; the installed program reads the installed config (through EMULATOR for a cross build);
# and, for a native package, every shared library the binaries load comes from a package the .deb depends on.
set -euo pipefail
BUILD=$(cd "$1" && pwd)
shift
EMULATOR=("$@")
WORK=$(mktemp -d "${TMPDIR:-/tmp}/uavm_package.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }

# -- the package ---------------------------------------------------------------------------------------------------
# Unset: the build's components (cmake/UavmPackaging.cmake), both packages.
COMPONENTS=${UAVM_PACKAGE_COMPONENTS:-}
(cd "$BUILD" && cpack -G DEB -B "$WORK/deb" ${COMPONENTS:+-D "CPACK_COMPONENTS_ALL=$COMPONENTS"} >"$WORK/cpack.log" 2>&1) ||
  { cat "$WORK/cpack.log" >&2; fail "cpack"; }
DEB=$(ls "$WORK"/deb/uavmosaic_*.deb 2>/dev/null | head -n 1)
[[ -n $DEB ]] || fail "no .deb written"
ARCH=$(dpkg-deb -f "$DEB" Architecture)
echo "package: $(basename "$DEB") ($(du -k "$DEB" | cut -f1) KiB)"
GROUND_DEB=
if [[ -z $COMPONENTS || ";$COMPONENTS;" == *";ground;"* ]]; then
  GROUND_DEB=$(ls "$WORK"/deb/uavmosaic-ground_*.deb 2>/dev/null | head -n 1)
  [[ -n $GROUND_DEB ]] || fail "no uavmosaic-ground .deb written"
  [[ $(dpkg-deb -f "$GROUND_DEB" Architecture) == "$ARCH" ]] || fail "the ground package's architecture differs"
  echo "package: $(basename "$GROUND_DEB") ($(du -k "$GROUND_DEB" | cut -f1) KiB)"
fi

# -- installed into a scratch root ------------------------------------------------------------------------------------
ROOT=$WORK/root
mkdir -p "$ROOT/var/lib/dpkg/info" "$ROOT/var/lib/dpkg/updates"
touch "$ROOT/var/lib/dpkg/status"
# --force-depends: the scratch root has no packages (the dependencies are checked below against the host instead);
# --force-architecture: an arm64 package on an amd64 dpkg.
dpkg --root="$ROOT" --force-script-chrootless --force-depends --force-architecture --log=/dev/null -i "$DEB" \
  ${GROUND_DEB:+"$GROUND_DEB"} >"$WORK/dpkg.log" 2>&1 || { cat "$WORK/dpkg.log" >&2; fail "dpkg -i"; }
dpkg --root="$ROOT" -s uavmosaic | grep -q '^Status: install ok installed' || fail "not installed"
if [[ -n $GROUND_DEB ]]; then
  dpkg --root="$ROOT" -s uavmosaic-ground | grep -q '^Status: install ok installed' || fail "ground tool not installed"
  dpkg --root="$ROOT" -L uavmosaic-ground | grep -qx /usr/bin/uavmosaic-ground || fail "uavmosaic-ground not listed"
  dpkg --root="$ROOT" -L uavmosaic | grep -q uavmosaic-ground && fail "the drone's package carries the ground tool"
  [[ -s $ROOT/usr/bin/uavmosaic-ground ]] || fail "missing /usr/bin/uavmosaic-ground"
fi
for f in usr/bin/uavmosaic-onboard usr/bin/uavmosaic-sim usr/bin/uavmosaic-eval usr/lib/uavmosaic/libuavm_video_reader.so \
  etc/uavmosaic/onboard.yaml \
  etc/default/uavmosaic-onboard lib/systemd/system/uavmosaic-onboard.service usr/share/doc/uavmosaic/README.md; do
  [[ -s $ROOT/$f ]] || fail "missing /$f"
  dpkg --root="$ROOT" -L uavmosaic | grep -qx "/$f" || fail "/$f not listed by dpkg -L"
done
dpkg-deb -f "$DEB" Depends | grep -q libopencv-core406 || fail "Depends lacks OpenCV"
[[ $(dpkg-deb -I "$DEB" conffiles) == *"/etc/uavmosaic/onboard.yaml"* ]] || fail "onboard.yaml is not a conffile"
file -b "$ROOT/usr/bin/uavmosaic-onboard" | grep -q "not stripped" && fail "binaries not stripped"
case $ARCH in
  amd64) file -b "$ROOT/usr/bin/uavmosaic-onboard" | grep -q "x86-64" || fail "amd64 package without x86-64 binary" ;;
  arm64) file -b "$ROOT/usr/bin/uavmosaic-onboard" | grep -q "ARM aarch64" || fail "arm64 package without aarch64 binary" ;;
esac
echo "installed: $(dpkg --root="$ROOT" -L uavmosaic | grep -c .) paths, binaries $(du -k "$ROOT/usr/bin" | cut -f1) KiB"

# -- the unit ---------------------------------------------------------------------------------------------------------
UNIT=$ROOT/lib/systemd/system/uavmosaic-onboard.service
for key in "Type=notify" "Restart=on-failure" "WatchdogSec=" "MemoryMax=" "--resume"; do
  grep -q -- "$key" "$UNIT" || fail "unit lacks $key"
done
if command -v systemd-analyze >/dev/null; then
  # The standard targets and units a Debian system has (from the host's systemd package), for the default
  # dependencies to resolve in the scratch root.
  cp -rn /lib/systemd/system/. "$ROOT/lib/systemd/system/"
  # --root: ExecStart's binary is looked up in the scratch root. Any message is a finding.
  if ! systemd-analyze verify --root="$ROOT" /lib/systemd/system/uavmosaic-onboard.service >"$WORK/verify.log" 2>&1 ||
    grep -q . "$WORK/verify.log"; then
    cat "$WORK/verify.log" >&2
    fail "systemd-analyze verify"
  fi
  echo "systemd-analyze verify: clean"
else
  fail "systemd-analyze missing (scripts/setup.sh installs systemd)"
fi

# -- the installed program reads the installed config -----------------------------------------------------------------
RUN=("${EMULATOR[@]}" "$ROOT/usr/bin/uavmosaic-onboard")
"${RUN[@]}" --config "$ROOT/etc/uavmosaic/onboard.yaml" --source replay:none --out "$WORK/none" --print-config \
  >"$WORK/config.txt" 2>&1 || { cat "$WORK/config.txt" >&2; fail "installed program rejects the installed config"; }
budget=$(sed -n 's/^memory_budget_mib: //p' "$WORK/config.txt")
max=$(sed -n 's/^MemoryMax=\([0-9]*\)M$/\1/p' "$UNIT")
[[ -n $budget && -n $max ]] && ((max > budget)) || fail "MemoryMax ($max) must exceed the budget ($budget)"
echo "config: budget $budget MiB, unit MemoryMax ${max} MiB"

# -- the installed program finds its video module (lib/uavmosaic beside bin/, not the build tree) -------------------------
# A file FFmpeg cannot read gets past the module: "cannot open video", not "video replay needs ...".
printf 'not a video' >"$WORK/broken.avi"
UAVM_VIDEO_READER= "${RUN[@]}" --source "replay:$WORK/broken.avi" --out "$WORK/video" >"$WORK/video.txt" 2>&1 || true
grep -qF "(read through $ROOT/usr/lib/uavmosaic/libuavm_video_reader.so)" "$WORK/video.txt" || { cat "$WORK/video.txt" >&2; fail "the installed video module is not found"; }
echo "video module: found under usr/lib/uavmosaic"

# -- the installed ground tool starts -----------------------------------------------------------------------------------
if [[ -n $GROUND_DEB ]]; then
  "${EMULATOR[@]}" "$ROOT/usr/bin/uavmosaic-ground" --help >"$WORK/ground.txt" 2>&1 ||
    { cat "$WORK/ground.txt" >&2; fail "the installed ground tool does not start"; }
  grep -q reconstruct "$WORK/ground.txt" || { cat "$WORK/ground.txt" >&2; fail "the ground tool's help lacks reconstruct"; }
  echo "ground tool: starts from its package"
fi

# -- dependencies: every library the binaries link is in a package the .deb names ---------------------------------------
if [[ $ARCH == "$(dpkg --print-architecture)" && ${#EMULATOR[@]} -eq 0 ]]; then
  depends=$(dpkg-deb -f "$DEB" Depends | tr ',' '\n' | sed 's/[[:space:]]*(.*//; s/^[[:space:]]*//')
  missing=0
  for bin in "$ROOT"/usr/bin/*; do
    # The binary's own NEEDED entries (what they load in turn is their packages' business).
    needed=$(readelf -d "$bin" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p')
    while read -r lib path; do
      grep -qx "$lib" <<<"$needed" || continue
      [[ $path == not ]] && { echo "$(basename "$bin"): $lib not found" >&2; missing=1; continue; }
      real=$(readlink -f "$path")
      pkg=$( (dpkg -S "$path" 2>/dev/null || dpkg -S "$real" 2>/dev/null) | head -n 1 | cut -d: -f1)
      [[ -z $pkg ]] && continue  # a file no package owns (e.g. an alternatives link): its target's package is listed
      grep -qx "$pkg" <<<"$depends" && continue
      # Through an alternatives link (libblas.so.3 -> ATLAS): the package of the link's target.
      echo "$(basename "$bin"): $lib is in $pkg, which the package does not depend on" >&2
      missing=1
    done < <(ldd "$bin" | awk '/=>/ { print $1, $3 }')
  done
  ((missing == 0)) || fail "undeclared dependencies"
  echo "dependencies: the package of every library the binaries link is in Depends"
fi
echo "PASS"
