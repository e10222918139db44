#!/usr/bin/env bash
# memory.sh DATA_DIR [OUT_DIR]
#
# Fixed memory, measured: uavmosaic-onboard under its default memory budget (256 MiB) on
#   - the same simulated flight (bench/plans/sim_memory.yaml over DATA_DIR/caliterra/images/IMG_9360.jpg, rendered
#     by the sim: source, nothing on disk) cut at 200 and at 2000 frames: peak RSS must stay flat
#     (RSS(2000) <= 1.1 x RSS(200)) and both within the budget;
#   - the full-resolution real flights (12 MP caliterra, brighton_beach): within the budget;
#   - flights of other frame sizes and aspects made from those (scaled to cover, centre-cropped, EXIF kept, by
#     uavm-reframe into a temporary folder): within the budget too, since it must hold for any frame size.
# One markdown table (OUT_DIR/table.md and $RESULTS_DIR/memory-<date>-<hostname>.md).
#
# Environment:
#   BUDGET_MIB        memory budget passed to the program (default 256)
#   LONG_FRAMES       frames of the long run (default 2000); SHORT_FRAMES (default 200); SIM=0 skips both
#   FLIGHTS_REAL      real flights (default "caliterra brighton_beach"; "" = none)
#   FLIGHTS_SIZES     resized flights NAME:SOURCE_FLIGHT:WIDTHxHEIGHT:FRAMES (default 12 MP 3:2 4272x2848 and 4:3
#                     3240x2430 from caliterra, 16:9 3840x2160 from brighton_beach; "" = none)
#   EXTRA_ARGS        more arguments for every run (e.g. "--config exp.yaml" to compare a setting)
#   UAVM_BUILD_DIR    build tree (default <repo>/build); UAVM_RESULTS_DIR (default bench/results)
set -euo pipefail
export LC_ALL=C

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,21p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"

DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
OUT_DIR=${2:-$RESULTS_DIR/run-memory-$STAMP}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS_BIN=$BUILD/firmware_app/uavmosaic-onboard
BUDGET_MIB=${BUDGET_MIB:-256}
LONG_FRAMES=${LONG_FRAMES:-2000}
SHORT_FRAMES=${SHORT_FRAMES:-200}
FLIGHTS_REAL=${FLIGHTS_REAL-caliterra brighton_beach}
FLIGHTS_SIZES=${FLIGHTS_SIZES-cal_4272x2848:caliterra:4272x2848:40 cal_3240x2430:caliterra:3240x2430:40 bb_3840x2160:brighton_beach:3840x2160:18}
REFRAME_BIN=$BUILD/bench/uavm-reframe
log() { echo "[memory] $*" >&2; }
command -v jq >/dev/null 2>&1 || { log "jq missing (apt-get install jq)"; exit 1; }
mkdir -p "$OUT_DIR" "$RESULTS_DIR"
OUT_DIR=$(cd "$OUT_DIR" && pwd)

# The plan with its canvas, so that the sim: source renders the flight in memory.
PLAN=$OUT_DIR/sim_memory.yaml
{ echo "canvas: $DATA_DIR/caliterra/images/IMG_9360.jpg"; cat "$SCRIPT_DIR/plans/sim_memory.yaml"; } >"$PLAN"

ROWS=()
declare -A PEAK
# run NAME SOURCE [extra args]: one onboard run under the watchdog; a table row from report.json.
run() {
  local name=$1 source=$2
  shift 2
  local dir=$OUT_DIR/$name
  rm -rf "$dir"
  log "$name: $source $*"
  # shellcheck disable=SC2086 # EXTRA_ARGS is a list of words
  run_watched "$dir" 0 0 "$OURS_BIN" --source "$source" --out "$dir" --memory-budget "$BUDGET_MIB" "$@" ${EXTRA_ARGS:-}
  local peak report=$dir/report.json
  peak=$(peak_mib)
  PEAK[$name]=$W_PEAK_KB
  if ((W_RC != 0)) || [[ ! -s $report ]]; then
    ROWS+=("| $name | failed (exit $W_RC) | | | | | | | | | | |")
    return 0
  fi
  ROWS+=("$(jq -r --arg name "$name" --arg peak "$peak" --arg wall "$(fmt "$W_WALL_S" 1)" '
    "| \($name) | \(.frames_in) | \(.registered) | \($wall) | \($peak) | " +
    "\(.memory.phase_peak_rss_mib.flight | floor) / \(.memory.phase_peak_rss_mib.solve | floor) / " +
    "\(.memory.phase_peak_rss_mib.compose | floor) | \(.memory.plan.sift_bands) / \(.memory.plan.queue_capacity) / " +
    "\(.memory.plan.feature_cache_mib | floor) / \(.memory.plan.relocalization_descriptors) / " +
    "\(.memory.plan.image_cache_mib | floor) / \(.memory.plan.tile_size) | " +
    "\(.memory.spilled.feature_sets_reloaded) / \(.memory.spilled.relocalization_thinnings) / " +
    "\(.memory.spilled.frame_redecodes) / \(.memory.spilled.refine_correspondences_skipped) | " +
    "\(.open_fds.flight_start) / \(.open_fds.flight_end) | \(.log.warnings) / \(.log.errors) | " +
    "\(.holdout_rms_px * 1000 | round / 1000) |"' "$report" || echo "| $name | report unreadable |")")
}
if [[ ${SIM:-1} != 0 ]]; then
  run "sim_$SHORT_FRAMES" "sim:$PLAN" --max-frames "$SHORT_FRAMES" --no-tiff
  run "sim_$LONG_FRAMES" "sim:$PLAN" --max-frames "$LONG_FRAMES" --no-tiff
fi
for f in $FLIGHTS_REAL; do
  run "$f" "replay:$DATA_DIR/$f/images"
done
if [[ -n $FLIGHTS_SIZES ]]; then
  [[ -x $REFRAME_BIN ]] || { log "$REFRAME_BIN missing (build the bench programs)"; exit 1; }
  SIZES_DIR=$(mktemp -d "${TMPDIR:-/tmp}/uavm-memory-sizes.XXXXXX")
  trap 'rm -rf "$SIZES_DIR"' EXIT
  for spec in $FLIGHTS_SIZES; do
    IFS=: read -r name flight size frames <<<"$spec"
    if ! "$REFRAME_BIN" --in "$DATA_DIR/$flight/images" --out "$SIZES_DIR/$name" --width "${size%x*}" \
      --height "${size#*x}" --frames "${frames:-0}" >&2; then
      ROWS+=("| $name | could not be made from $flight | | | | | | | | | | |")
      continue
    fi
    run "$name" "replay:$SIZES_DIR/$name"
    rm -rf "${SIZES_DIR:?}/$name"
  done
fi

short_kb=${PEAK[sim_$SHORT_FRAMES]:-0}
long_kb=${PEAK[sim_$LONG_FRAMES]:-0}
ratio="—"
((short_kb > 0)) && ratio=$(awk -v a="$long_kb" -v b="$short_kb" 'BEGIN { printf "%.3f", a / b }')
{
  echo "Memory benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc), CPU: $(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -n 1), budget $BUDGET_MIB MiB"
  echo
  echo "| run | frames | registered | wall s | peak RSS MiB | phase peaks MiB: flight / end solves / compositing | plan: detector bands / queue / feature cache MiB / relocalisation descriptors / image cache MiB / tile | spilled: feature reloads / index thinnings / frame re-decodes / solver points skipped | open fds: flight start / end | log warnings / errors | held-out RMS px |"
  echo "|---|---:|---:|---:|---:|---|---|---|---|---|---:|"
  printf '%s\n' "${ROWS[@]}"
  echo
  echo "RSS(${LONG_FRAMES}) / RSS(${SHORT_FRAMES}) = $ratio (target <= 1.1); budget $BUDGET_MIB MiB."
  echo "peak RSS: max VmHWM polled every 0.2 s, outside the process; phase peaks: the program's own high-water mark, reset between phases. The 2000-frame run is also the soak: open file descriptors and log warnings must not grow with the flight. sim runs: --no-tiff (the mosaic of a sim flight is not the point here); real runs write mosaic.tif. NAME_WxH runs: the real flight scaled to cover WxH and centre-cropped (FLIGHTS_SIZES)."
} >"$OUT_DIR/table.md"
cp "$OUT_DIR/table.md" "$RESULTS_DIR/memory-$STAMP-$(hostname).md"
cat "$OUT_DIR/table.md"
