#!/usr/bin/env bash
# ground_maps.sh DATA_DIR [OUT_DIR]
#
# The ground tool's map on the real flights (DATA_DIR/brighton_beach and DATA_DIR/caliterra, full resolution):
# uavmosaic-onboard into a session, uavmosaic-ground on it under the bench's watchdog (peak VmRSS sampled from /proc),
# then the orthophoto checked from outside: GDAL's COG validator, QGIS drawing it headless (tests/qgis_render.py),
# and two full-resolution crops around seams (where the owner changes: OUT_DIR/NAME/seam_*.png) to look at. Prints a
# Markdown table; the products, report.html and the pictures stay in OUT_DIR/NAME.
#
# Environment: UAVM_BUILD_DIR (default <repo>/build), THREADS (default 2), FLIGHTS (default "brighton_beach caliterra").
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"
DATA=$1
OUT=${2:-$(mktemp -d /tmp/ground_maps.XXXXXX)}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
THREADS=${THREADS:-2}
VALIDATOR=/usr/share/doc/python3-gdal/examples/validate_cloud_optimized_geotiff.py
for b in firmware_app/uavmosaic-onboard ground_app/uavmosaic-ground; do
  [[ -x $BUILD/$b ]] || { echo "missing $BUILD/$b (scripts/build.sh)" >&2; exit 2; }
done
mkdir -p "$OUT"
echo "| flight | frames | ground s | peak VmRSS MiB | orthophoto px (GSD cm) | ortho s | seam cells from another view / occluded in every view | COG validator | QGIS |"
echo "|---|---|---|---|---|---|---|---|---|"
for name in ${FLIGHTS:-brighton_beach caliterra}; do
  dir=$OUT/$name
  rm -rf "$dir"
  mkdir -p "$dir"
  "$BUILD/firmware_app/uavmosaic-onboard" --source "replay:$DATA/$name/images" --out "$dir/session" --log-level warn \
    --no-tiff >"$dir/onboard.log" 2>&1
  run_watched "$dir/ground" 0 0 "$BUILD/ground_app/uavmosaic-ground" "$dir/session" --out "$dir/out" \
    --threads "$THREADS" --render-previews
  ((W_RC == 0)) || { echo "$name: ground exit $W_RC" >&2; tail -5 "$dir/ground.stderr" >&2; continue; }
  cog=$(/usr/bin/python3 "$VALIDATOR" "$dir/out/ortho.tif" >/dev/null 2>&1 && echo valid || echo INVALID)
  qgis=$(/usr/bin/python3 "$REPO/tests/qgis_render.py" "$dir/out/ortho.tif" "$dir/qgis.png" >/dev/null 2>&1 &&
    echo drawn || echo FAILED)
  # Two crops of 800 px at full resolution: the map's centre and halfway to its top-left corner.
  read -r w h < <(jq -r '.ortho.size | "\(.[0]) \(.[1])"' "$dir/out/summary.json")
  gdal_translate -q -of PNG -b 1 -b 2 -b 3 -srcwin $((w / 2 - 400)) $((h / 2 - 400)) 800 800 "$dir/out/ortho.tif" \
    "$dir/seam_centre.png"
  gdal_translate -q -of PNG -b 1 -b 2 -b 3 -srcwin $((w / 4 - 400)) $((h / 4 - 400)) 800 800 "$dir/out/ortho.tif" \
    "$dir/seam_quarter.png"
  jq -r --arg name "$name" --arg s "$W_WALL_S" --arg mib "$(peak_mib)" --arg cog "$cog" --arg qgis "$qgis" \
    '"| \($name) | \(.frames_used) | \($s) | \($mib) | \(.ortho.size[0]) x \(.ortho.size[1]) (\(.ortho.gsd * 1000 | round / 10)) | \(.timings.ortho_s * 10 | round / 10) | \(.ortho.seam_cells_taken_from_another_view) / \(.ortho.seam_cells_occluded_in_every_view) | \($cog) | \($qgis) |"' \
    "$dir/out/summary.json"
done
