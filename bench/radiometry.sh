#!/usr/bin/env bash
# radiometry.sh DATA_DIR [OUT_DIR]
#
# Issue 19's photometric table. Simulated flights over DATA_DIR/caliterra/images/IMG_9360.jpg (bench/plans/
# radiometry_{clean,vignetting,exposure,hotspot,hotspot_low,hotspot_shading,shading}.yaml: an ideal camera; vignetting
# 0.6; vignetting 0.6 + exposure +-25 % + white balance +-5 %; the same camera at +-20 % under a high sun: a 35 %
# opposition hotspot and the drone's shadow 12 deg off nadir; another camera and sun (20 %); a 40 % hotspot near nadir on
# an off-centre falloff; the off-centre falloff alone) through uavmosaic-onboard with the radiometric correction off,
# with the radial model only (issue 37's flat field and hotspot off) and on, and through cv::Stitcher
# SCANS without and with its gain compensation (uavm-stitcher-bench --exposure none|gain|channels); each mosaic's
# low-frequency brightness error after one gain per channel (uavmosaic-eval image --footprint-px: placed on the
# canvas by SIFT + RANSAC, the same measure for every tool). Real flights (DATA_DIR/{brighton_beach,caliterra}/images,
# FLIGHTS_REAL): the per-frame gains the correction found (radiometry.csv) against the camera's recorded exposure
# (EXIF ExposureTime x ISO / FNumber^2): correlation and RMS of the centred logs, with the vignetting found.
# Prints one markdown table per part, also saved to $UAVM_RESULTS_DIR (default bench/results)/radiometry-<date>.md.
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
OUT_DIR=${2:-/tmp/uavm-radiometry-$STAMP}
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS=$BUILD/firmware_app/uavmosaic-onboard
SIM=$BUILD/tools/uavmosaic-sim
EVAL=$BUILD/tools/uavmosaic-eval
STITCHER=$BUILD/bench/uavm-stitcher-bench
FLIGHTS_REAL=${FLIGHTS_REAL-brighton_beach caliterra}
CANVAS=$DATA_DIR/caliterra/images/IMG_9360.jpg
FOOTPRINT_PX=768  # 640 px frames at gsd 1.2
mkdir -p "$OUT_DIR" "$RESULTS_DIR"
log() { echo "[radiometry] $*" >&2; }
command -v jq >/dev/null || { log "jq missing (apt-get install jq)"; exit 1; }
printf 'radiometry:\n  enabled: false\n' >"$OUT_DIR/off.yaml"
printf 'radiometry:\n  flat_field: false\n  hotspot: false\n' >"$OUT_DIR/radial.yaml"  # the model before issue 37

photometric() {  # MOSAIC -> % or "-"
  "$EVAL" image --mosaic "$1" --canvas "$CANVAS" --footprint-px "$FOOTPRINT_PX" --json "$1.eval.json" >/dev/null 2>&1 &&
    jq -r '.photometric.rms_percent // "-" | if type == "number" then (. * 100 | round / 100) else . end' "$1.eval.json" ||
    echo "-"
}

sim_row() {
  local name=$1 dir=$OUT_DIR/$1
  rm -rf "$dir" && mkdir -p "$dir"
  "$SIM" --plan "$REPO/bench/plans/radiometry_$name.yaml" --canvas "$CANVAS" --out "$dir/flight" >"$dir/sim.log" 2>&1
  local frames; frames=$(ls "$dir/flight/images" | wc -l)
  "$OURS" --source "replay:$dir/flight/images" --out "$dir/off" --no-products --config "$OUT_DIR/off.yaml" >"$dir/off.log" 2>&1
  "$OURS" --source "replay:$dir/flight/images" --out "$dir/radial" --no-products --config "$OUT_DIR/radial.yaml" >"$dir/radial.log" 2>&1
  "$OURS" --source "replay:$dir/flight/images" --out "$dir/on" --no-products >"$dir/on.log" 2>&1
  local cells=("$(photometric "$dir/off/mosaic.png")" "$(photometric "$dir/radial/mosaic.png")" "$(photometric "$dir/on/mosaic.png")")
  for e in none gain channels; do
    "$STITCHER" --images "$dir/flight/images" --out "$dir/stitcher-$e.png" --exposure "$e" >"$dir/stitcher-$e.json" 2>&1 || true
    cells+=("$(photometric "$dir/stitcher-$e.png") ($(jq -r '.frames_in_result // "-"' "$dir/stitcher-$e.json" 2>/dev/null || echo -)/$frames)")
  done
  local corner; corner=$(jq -r '.radiometry.corner_falloff_bgr // [] | map(. * 1000 | round / 1000) | join(" ")' "$dir/on/report.json")
  local beyond; beyond=$(jq -r '.radiometry | [(if .flat_field then "flat field" else empty end), (if .hotspot.found then "hotspot x\(.hotspot.peak_gain * 100 | round / 100)" else empty end)] | join(", ")' "$dir/on/report.json")
  echo "| $name | $frames | ${cells[0]} | ${cells[1]} | ${cells[2]} | ${cells[3]} | ${cells[4]} | ${cells[5]} | $corner | ${beyond:--} |"
}

real_row() {
  local flight=$1 dir=$OUT_DIR/$1
  rm -rf "$dir"
  "$OURS" --source "replay:$DATA_DIR/$flight/images" --out "$dir" --no-products >"$OUT_DIR/$flight.log" 2>&1
  python3 "$SCRIPT_DIR/radiometry_exif.py" "$dir/radiometry.csv" "$DATA_DIR/$flight/images" "$flight" \
    "$(jq -r '.radiometry.corner_falloff_bgr // [] | map(. * 1000 | round / 1000) | join(" ")' "$dir/report.json")"
}

{
  echo "Radiometry benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc)"
  echo
  echo "Low-frequency brightness error of the mosaic against the canvas after one gain per channel, % RMS (Gaussian sigma"
  echo "a quarter of a footprint); cv::Stitcher cells add its frames kept / frames flown."
  echo
  echo "| flight | frames | ours, correction off | ours, radial model only | ours, on | Stitcher SCANS (no compensation) | Stitcher + GainCompensator | Stitcher + ChannelsCompensator | vignetting corner found (B G R) | beyond the lens |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|---|---|"
  for name in clean vignetting exposure hotspot hotspot_low hotspot_shading shading; do log "sim $name"; sim_row "$name"; done
  echo
  echo "Real flights: gains found (radiometry.csv, green) against the recorded exposure (EXIF ExposureTime x ISO / FNumber^2)."
  echo
  echo "| flight | frames | correlation of logs | RMS of log difference | spread of log exposure | vignetting corner found (B G R) |"
  echo "|---|---:|---:|---:|---:|---|"
  for flight in $FLIGHTS_REAL; do log "$flight"; real_row "$flight"; done
} | tee "$RESULTS_DIR/radiometry-$STAMP.md"
