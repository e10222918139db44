#!/usr/bin/env bash
# lens.sh DATA_DIR [OUT_DIR]
#
# Issue 19's lens table. Simulated flights over DATA_DIR/caliterra/images/IMG_9360.jpg (bench/plans/lens_*.yaml:
# barrel lenses of -0.1 and -0.039 at the half-diagonal, and the ideal radiometry_clean.yaml) through uavmosaic-onboard
# without any lens handling (camera.database and camera.self_calibrate off) and with the defaults; each session's
# error against the truth (uavmosaic-eval with the truth's gt_camera.yaml and the session's camera.yaml). Real flights
# (DATA_DIR/{brighton_beach,caliterra}/images, FLIGHTS_REAL), both ways in the same run: report.json holdout_rms_px
# (held-out correspondences, working pixels), the lens chosen and the self-calibration's verdict, wall time, and the
# quick-look mosaics side by side (<results>/lens-<date>-<flight>.jpg).
# Prints one markdown table per part, also saved to $UAVM_RESULTS_DIR (default bench/results)/lens-<date>.md.
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
OUT_DIR=${2:-/tmp/uavm-lens-$STAMP}
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS=$BUILD/firmware_app/uavmosaic-onboard
SIM=$BUILD/tools/uavmosaic-sim
EVAL=$BUILD/tools/uavmosaic-eval
SIDE=$BUILD/bench/uavm-side-by-side
FLIGHTS_REAL=${FLIGHTS_REAL-brighton_beach caliterra}
CANVAS=$DATA_DIR/caliterra/images/IMG_9360.jpg
mkdir -p "$OUT_DIR" "$RESULTS_DIR"
log() { echo "[lens] $*" >&2; }
command -v jq >/dev/null || { log "jq missing (apt-get install jq)"; exit 1; }
printf 'camera:\n  database: false\n  self_calibrate: false\n' >"$OUT_DIR/none.yaml"
round3() { jq -r "if type == \"number\" then (. * 1000 | round / 1000) else \"-\" end"; }

sim_row() {  # NAME PLAN
  local name=$1 dir=$OUT_DIR/$1
  rm -rf "$dir" && mkdir -p "$dir"
  "$SIM" --plan "$2" --canvas "$CANVAS" --out "$dir/flight" >"$dir/sim.log" 2>&1
  local truth; truth=$(grep -o 'half-diagonal: [-0-9.e]*' "$dir/flight/gt_camera.yaml" | awk '{print $2}' || true)
  local cells=()
  for mode in none defaults; do
    local cfg=(); [[ $mode == none ]] && cfg=(--config "$OUT_DIR/none.yaml")
    "$OURS" --source "replay:$dir/flight/images" --out "$dir/$mode" --no-products "${cfg[@]}" >"$dir/$mode.log" 2>&1
    "$EVAL" --session "$dir/$mode" --gt "$dir/flight/gt.csv" --session-camera "$dir/$mode/camera.yaml" \
      --no-photometric --json "$dir/$mode.eval.json" >/dev/null 2>&1
    cells+=("$(jq '.rms_px' "$dir/$mode.eval.json" | round3)")
  done
  local found; found=$(jq '.lens.final.distortion_at_half_diagonal' "$dir/defaults/report.json" | round3)
  local verdict; verdict=$(jq -r '.lens.self_calibration | if .accepted then "accepted" else "refused: " + .why end' \
    "$dir/defaults/report.json")
  echo "| $name | ${truth:-0} | ${cells[0]} | ${cells[1]} | $found | $verdict |"
}

real_row() {  # FLIGHT
  local flight=$1 dir=$OUT_DIR/$1 cells=()
  rm -rf "$dir" && mkdir -p "$dir"
  for mode in none defaults; do
    local cfg=(); [[ $mode == none ]] && cfg=(--config "$OUT_DIR/none.yaml")
    local t0; t0=$(date +%s.%N)
    "$OURS" --source "replay:$DATA_DIR/$flight/images" --out "$dir/$mode" "${cfg[@]}" >"$dir/$mode.log" 2>&1
    cells+=("$(jq '.holdout_rms_px' "$dir/$mode/report.json" | round3)" "$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')")
  done
  local r=$dir/defaults/report.json
  local lens; lens=$(jq -r '.lens | .prepared_with + (if .detail != "" then " (" + .detail + ")" else "" end)' "$r")
  local prepared; prepared=$(jq '.lens.prepared_distortion_at_half_diagonal' "$r" | round3)
  local final; final=$(jq '.lens.final.distortion_at_half_diagonal' "$r" | round3)
  local verdict; verdict=$(jq -r '.lens.self_calibration | (if .accepted then "accepted" else "refused: " + .why end) +
    " (held-out " + (.holdout_rms_px_without * 1000 | round / 1000 | tostring) + " -> " +
    (.holdout_rms_px_with * 1000 | round / 1000 | tostring) + " px, " + (.seconds * 10 | round / 10 | tostring) + " s)"' "$r")
  [[ -x $SIDE ]] && "$SIDE" "$dir/none/mosaic.png" "$dir/defaults/mosaic.png" "$RESULTS_DIR/lens-$STAMP-$flight.jpg" \
    >/dev/null 2>&1 || true
  echo "| $flight | ${cells[0]} | ${cells[2]} | ${cells[1]} / ${cells[3]} | $lens | $prepared | $final | $verdict |"
}

{
  echo "Lens benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc), $(git -C "$REPO" rev-parse --short HEAD)"
  echo
  echo "Simulated flights: error of transforms.csv against the truth, px RMS at the original resolution (uavmosaic-eval,"
  echo "undistorted with the truth's and the session's lens); distortion given as the radial displacement at the"
  echo "half-diagonal (share of its radius)."
  echo
  echo "| flight | lens (truth) | no lens handling | defaults | lens found | self-calibration |"
  echo "|---|---:|---:|---:|---:|---|"
  sim_row barrel "$REPO/bench/plans/lens_barrel.yaml"
  sim_row mild "$REPO/bench/plans/lens_mild.yaml"
  sim_row ideal "$REPO/bench/plans/radiometry_clean.yaml"
  echo
  echo "Real flights, every default product, both runs in this one: report.json holdout_rms_px (held-out"
  echo "correspondences after the final solve, working pixels), wall seconds."
  echo
  echo "| flight | held-out px, no lens handling | held-out px, defaults | wall s (none / defaults) | lens prepared with | its distortion | final distortion | self-calibration |"
  echo "|---|---:|---:|---:|---|---:|---:|---|"
  for flight in $FLIGHTS_REAL; do log "$flight"; real_row "$flight"; done
} | tee "$RESULTS_DIR/lens-$STAMP.md"
