#!/usr/bin/env bash
# flight_length.sh DATA_DIR [FRAMES]
#
# Per-frame cost along a long flight: uavmosaic-onboard on the memory benchmark's simulated flight
# (bench/plans/sim_memory.yaml over DATA_DIR/caliterra/images/IMG_9360.jpg, rendered in memory), FRAMES frames
# (default 2000). Prints the median per-frame time (the pipeline's own timer, one debug log line per frame) for each
# block of 100 frames, then the ratio of frames 1800-2000 to frames 100-300 (target <= 1.15: a frame late in a long
# flight must cost what an early one does), registered frames and peak RSS. Saved under bench/results/.
#
# Environment: UAVM_BUILD_DIR (default <repo>/build), UAVM_RESULTS_DIR (default bench/results), EXTRA_ARGS.
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
DATA_DIR=$(cd "$1" && pwd)
FRAMES=${2:-2000}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
STAMP=$(date +%Y%m%d-%H%M%S)
OUT=$(mktemp -d "${TMPDIR:-/tmp}/uavm_flight_length.XXXXXX")
trap 'rm -rf "$OUT"' EXIT
mkdir -p "$RESULTS_DIR"

PLAN=$OUT/sim_memory.yaml
{ echo "canvas: $DATA_DIR/caliterra/images/IMG_9360.jpg"; cat "$SCRIPT_DIR/plans/sim_memory.yaml"; } >"$PLAN"
echo "[flight_length] $FRAMES frames of sim_memory.yaml" >&2
# shellcheck disable=SC2086 # EXTRA_ARGS is a list of words
run_watched "$OUT/run" 0 0 "$BUILD/firmware_app/uavmosaic-onboard" --source "sim:$PLAN" --max-frames "$FRAMES" \
  --out "$OUT/session" --no-tiff --log-level debug ${EXTRA_ARGS:-}
((W_RC == 0)) || { echo "[flight_length] run failed (exit $W_RC)" >&2; tail -20 "$OUT/run.stderr" >&2; exit 1; }

# "frame 1234 (its name) processed in 56.7 ms" -> "1234 56.7"
cat "$OUT/run.stdout" "$OUT/run.stderr" | sed -nE 's/.*frame ([0-9]+) (\([^)]*\) )?processed in ([0-9.]+) ms.*/\1 \3/p' |
  sort -n >"$OUT/frame_ms.txt"
median_of() {  # median_of FIRST LAST: median ms of frames FIRST..LAST-1
  awk -v a="$1" -v b="$2" '$1 >= a && $1 < b { print $2 }' "$OUT/frame_ms.txt" | sort -g |
    awk '{ v[NR] = $1 } END { if (NR == 0) print "nan"; else if (NR % 2) print v[(NR + 1) / 2]; else print (v[NR / 2] + v[NR / 2 + 1]) / 2 }'
}
{
  echo "Flight length benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), load $(cut -d' ' -f1-3 /proc/loadavg)"
  echo
  echo "sim_memory.yaml, $FRAMES frames${EXTRA_ARGS:+, $EXTRA_ARGS}: registered $(jq .registered "$OUT/session/report.json"), wall $(fmt "$W_WALL_S" 1) s, peak RSS $(peak_mib) MiB"
  echo
  echo "| frames | median ms/frame |"
  echo "|---|---:|"
  for ((a = 0; a < FRAMES; a += 100)); do
    echo "| $a-$((a + 99)) | $(median_of "$a" $((a + 100))) |"
  done
  early=$(median_of 100 300)
  late=$(median_of $((FRAMES - 200)) "$FRAMES")
  echo
  echo "median of frames 100-299: $early ms; of frames $((FRAMES - 200))-$((FRAMES - 1)): $late ms; ratio $(awk -v a="$early" -v b="$late" 'BEGIN { printf "%.3f", b / a }') (target <= 1.15)"
} | tee "$RESULTS_DIR/flight-length-$STAMP-$(hostname).md"
