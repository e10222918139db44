#!/usr/bin/env bash
# Installs the Debian 12 packages the build needs, plus any named as arguments (e.g. `setup.sh clang`). Idempotent:
# does nothing when all are present.
set -euo pipefail
PACKAGES=(
  build-essential cmake ninja-build pkg-config
  lld  # the linker (cmake/UavmLinker.cmake): ~6x faster than GNU ld on the tree's ~110 programs
  libopencv-dev libeigen3-dev libgdal-dev libdeflate-dev zlib1g-dev gdal-bin libexiv2-dev
  libcli11-dev libspdlog-dev libyaml-cpp-dev nlohmann-json3-dev
  libceres-dev libsystemd-dev systemd file
  libcamera-dev libcamera-ipa
  libgtest-dev libgmock-dev libbenchmark-dev
  libcpp-httplib-dev libjs-leaflet chromium python3-gdal python3-qgis curl
  libssl-dev openssl  # MAVLink signing (SHA-256), the live server's HTTPS; the tests make their CA with openssl
  jq time  # bench/ground_brighton.sh: summary.json fields, peak RSS (/usr/bin/time -v)
  clang-tidy clang-format  # scripts/lint.sh --function-size and --check (CI steps)
  libgps-dev  # --telemetry gpsd:HOST:PORT (hal/telemetry/gpsd_source.cpp)
  liblensfun-dev liblensfun-data-v1  # the camera database for lens distortion (core/lens/lens_database.cpp)
  # tests/gpsd_test.cpp: gpsfake starts its own gpsd on a free port; the system's (gpsd.socket, port 2947, started
  # by the package where systemd runs) is not used and not in the way.
  gpsd gpsd-clients
  python3-skimage  # tests/daisy_test.cpp: scikit-image's DAISY, the reference for core/stereo/daisy.cpp
  colmap  # the ground tool's peer: tests/ground_e2e_test.cpp has COLMAP read our model; bench/ground_vs_colmap.sh
  nodejs  # test peers (tests/telemetry/run_peer.sh: node-mavlink from the npm registry)
  "$@"
)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# Debian's nodejs comes without npm (its own package); other builds of nodejs (NodeSource) bring it and conflict.
command -v npm >/dev/null 2>&1 || missing+=(npm)
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages present"
  exit 0
fi
echo "setup: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
