#!/usr/bin/env bash
# make_sysroot.sh [DIR] — the arm64 Debian 12 sysroot that toolchains/aarch64-linux-gnu.cmake builds against.
#
# Idempotent: when DIR already holds a sysroot made from the same package list, nothing is done. Default DIR:
# $UAVM_SYSROOT, else ${UAVM_CACHE_DIR:-/var/cache/uavmosaic}/sysroot-arm64-bookworm (outside the clone, so that CI
# machines and later clones reuse it). Prints the sysroot's path on its last line.
#
# Why a folder and not multiarch: libopencv-dev:arm64 (and GDAL, Ceres) cannot be co-installed with the amd64
# packages on Debian 12 — apt would remove the native build's libraries. mmdebstrap's "extract" variant unpacks the
# arm64 packages without running their maintainer scripts, so two things those scripts would do are done here:
# absolute .so symlinks are made relative to the sysroot, and the BLAS/LAPACK alternatives links are created.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
CACHE="${UAVM_CACHE_DIR:-/var/cache/uavmosaic}"
DIR="${1:-${UAVM_SYSROOT:-$CACHE/sysroot-arm64-bookworm}}"

# What the project links (scripts/setup.sh lists the amd64 equivalents), plus the C/C++ runtime headers.
PACKAGES=(
  libc6-dev libstdc++-12-dev linux-libc-dev
  libopencv-dev libeigen3-dev libgdal-dev libexiv2-dev libjpeg-dev
  libcli11-dev libspdlog-dev libyaml-cpp-dev nlohmann-json3-dev
  libceres-dev libsystemd-dev libcamera-dev libcpp-httplib-dev
  libgtest-dev libgmock-dev libbenchmark-dev
)
STAMP_TEXT="bookworm arm64 v1: ${PACKAGES[*]}"
if [[ -f $DIR/.uavm-sysroot && "$(cat "$DIR/.uavm-sysroot")" == "$STAMP_TEXT" ]]; then
  echo "sysroot: present ($DIR)" >&2
  echo "$DIR"
  exit 0
fi

bash "$ROOT/scripts/setup.sh" crossbuild-essential-arm64 qemu-user mmdebstrap >&2
echo "sysroot: making $DIR (arm64 packages, ~1.6 GB)" >&2
rm -rf "$DIR.part"
mkdir -p "$(dirname "$DIR")"
include=$(IFS=,; echo "${PACKAGES[*]}")
mmdebstrap --quiet --mode=root --variant=extract --architectures=arm64 --include="$include" bookworm "$DIR.part" \
  "deb http://deb.debian.org/debian bookworm main" \
  "deb http://deb.debian.org/debian bookworm-updates main" \
  "deb http://deb.debian.org/debian-security bookworm-security main" >&2

# Absolute symlinks point into the host once seen from outside the sysroot: make them relative.
while IFS= read -r -d '' link; do
  target=$(readlink "$link")
  [[ $target == /* ]] || continue
  rel=$(realpath -m --relative-to="$(dirname "$link")" "$DIR.part$target")
  ln -sfn "$rel" "$link"
done < <(find "$DIR.part" -type l -print0)

# The alternatives that libblas3 / liblapack3's postinst would register (OpenCV and Ceres link them).
lib="$DIR.part/usr/lib/aarch64-linux-gnu"
for name in blas lapack; do
  for impl in "$lib/atlas/lib$name.so.3" "$lib/openblas-pthread/lib$name.so.3" "$lib/$name/lib$name.so.3"; do
    if [[ -e $impl ]]; then
      ln -sfn "$(realpath --relative-to="$lib" "$impl")" "$lib/lib$name.so.3"
      ln -sfn "lib$name.so.3" "$lib/lib$name.so"
      break
    fi
  done
  [[ -e $lib/lib$name.so.3 ]] || { echo "sysroot: no lib$name.so.3 implementation unpacked" >&2; exit 1; }
done

# CMake package files written for the target name libraries by absolute path (Ceres: /usr/lib/.../liblapack.so):
# prefix them with ${CMAKE_SYSROOT}, which CMake expands when the file is included, so the sysroot can live anywhere.
find "$DIR.part/usr/lib/aarch64-linux-gnu/cmake" "$DIR.part/usr/lib/cmake" "$DIR.part/usr/share" -name '*.cmake' \
  -exec grep -l '[";]/usr/lib/aarch64-linux-gnu/lib' {} + 2>/dev/null |
  xargs -r sed -i -E 's#([";])(/usr/lib/aarch64-linux-gnu/lib[^;"]*)#\1${CMAKE_SYSROOT}\2#g'

echo "$STAMP_TEXT" >"$DIR.part/.uavm-sysroot"
rm -rf "$DIR"
mv "$DIR.part" "$DIR"
echo "sysroot: ready ($(du -sh "$DIR" | cut -f1))" >&2
echo "$DIR"
