#!/usr/bin/env bash
# Set-up-free demo: installs what is missing, builds, and mosaics the bundled brighton_beach_small flight.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_BUILD_DIR:-$ROOT/build}"
OUT="${1:-$ROOT/demo_out}"
bash "$ROOT/scripts/build.sh"
"$BUILD_DIR/firmware_app/uavmosaic-onboard" \
  --source "replay:$ROOT/tests/data/brighton_beach_small/images" --out "$OUT"
echo
echo "demo: mosaic written to $OUT/mosaic.png (tiled GeoTIFF container: $OUT/mosaic.tif, report: $OUT/report.json)"
