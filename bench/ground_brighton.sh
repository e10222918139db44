#!/usr/bin/env bash
# ground_brighton.sh DATA_DIR [OUT_DIR]
#
# The ground tool on the full-resolution brighton_beach flight (DATA_DIR/brighton_beach/images, 18 frames 4000x2250):
# uavmosaic-onboard into a session, then uavmosaic-ground on it (with --render-previews). Prints a markdown table of
# stage times, BA RMS before/after (original-resolution pixels), sparse/dense points and peak RSS (/usr/bin/time -v),
# and keeps it with the two previews in bench/results/ground-brighton-<date>-vm.md (+ PNGs).
#
# Environment: UAVM_BUILD_DIR (default <repo>/build-sfm), GROUND_ARGS (extra uavmosaic-ground options),
#              THREADS (default 2), UAVM_RESULTS_DIR (default bench/results).
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
DATA=$1
OUT=${2:-$(mktemp -d /tmp/ground_brighton.XXXXXX)}
BUILD=${UAVM_BUILD_DIR:-$REPO/build-sfm}
RESULTS=${UAVM_RESULTS_DIR:-$REPO/bench/results}
THREADS=${THREADS:-2}
ONBOARD=$BUILD/firmware_app/uavmosaic-onboard
GROUND=$BUILD/ground_app/uavmosaic-ground
for b in "$ONBOARD" "$GROUND"; do [[ -x $b ]] || { echo "missing $b (build it first)" >&2; exit 2; }; done
[[ -d $DATA/brighton_beach/images ]] || { echo "no $DATA/brighton_beach/images" >&2; exit 2; }
mkdir -p "$OUT" "$RESULTS"

peak_mib() { awk -F: '/Maximum resident set size/ {printf "%.0f", $2/1024}' "$1"; }
wall_s() { awk '/Elapsed \(wall clock\)/ {n=split($NF,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; printf "%.1f", s}' "$1"; }

rm -rf "$OUT/session" "$OUT/ground"
/usr/bin/time -v "$ONBOARD" --source "replay:$DATA/brighton_beach/images" --out "$OUT/session" --log-level warn \
  --no-tiff 2>"$OUT/onboard.time" >/dev/null
# shellcheck disable=SC2086
/usr/bin/time -v "$GROUND" "$OUT/session" --out "$OUT/ground" --threads "$THREADS" --render-previews ${GROUND_ARGS:-} \
  2>"$OUT/ground.time"

S=$OUT/ground/summary.json
stamp=$(date -u +%Y%m%d-%H%M%S)
table=$OUT/table.md
{
  echo "# uavmosaic-ground on brighton_beach (full resolution) — $stamp, $(nproc) cores, threads $THREADS"
  echo
  echo "Command: \`uavmosaic-ground SESSION --out DIR --threads $THREADS --render-previews ${GROUND_ARGS:-}\`"
  echo
  echo "| stage | seconds |"
  echo "|---|---|"
  echo "| onboard (session) | $(wall_s "$OUT/onboard.time") |"
  jq -r '.timings | to_entries[] | "| \(.key) | \(.value*10|round/10) |"' "$S"
  echo "| ground wall (time -v) | $(wall_s "$OUT/ground.time") |"
  echo
  echo "| figure | value |"
  echo "|---|---|"
  jq -r '"| frames used | \(.frames_used) |",
         "| keypoints / frame (mean) | \(.keypoints_per_frame_mean|round) |",
         "| pairs verified / listed | \(.pairs_verified) / \(.pairs_listed) |",
         "| tracks | \(.tracks) |",
         "| BA RMS before (initial poses, px) | \(.ba_rms_before_px*1000|round/1000) |",
         "| BA RMS after (px) | \(.ba_rms_after_px*1000|round/1000) |",
         "| observations kept / in tracks | \(.observations_kept) / \(.observations_in_tracks) |",
         "| sparse points | \(.sparse_points) |",
         "| dense pairs | \(.dense.pairs|length) |",
         "| dense points raw / fused | \(.dense.raw_points) / \(.dense_points) |",
         "| focal px initial / adjusted | \(.focal_initial_px*10|round/10) / \(.camera.fx*10|round/10) |",
         "| k1 k2 p1 p2 | \(.camera.k1) \(.camera.k2) \(.camera.p1) \(.camera.p2) |",
         "| georef RMS to GPS (m) | \(.georef.rms_m // "n/a") |",
         "| CRS | \(.crs) |"' "$S"
  echo "| peak RSS onboard / ground (MiB) | $(peak_mib "$OUT/onboard.time") / $(peak_mib "$OUT/ground.time") |"
  echo
  echo "BA rounds (before -> after, reject threshold, points):"
  echo
  jq -r '.ba_rounds[] | "- \(.rms_before_px*1000|round/1000) -> \(.rms_after_px*1000|round/1000) px, \(.iterations) it, \(.seconds*10|round/10) s, reject > \(.reject_above_px // "final") px, points \(.points_after_reject // .points)"' "$S"
} >"$table"
cat "$table"
base=$RESULTS/ground-brighton-$stamp-vm
cp "$table" "$base.md"
for p in cloud dsm; do
  [[ -f $OUT/ground/preview_$p.png ]] && cp "$OUT/ground/preview_$p.png" "$base-$p.png"
done
echo "saved $base.md (+ previews)" >&2
