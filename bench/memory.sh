#!/usr/bin/env bash
# memory.sh DATA_DIR [OUT_DIR]
#
# Fixed memory, measured from outside the process: uavmosaic-onboard under its default memory budget (256 MiB), its
# VmRSS and RssAnon sampled every 50 ms from /proc/PID/status and attributed to the phase the program is in (the name
# of its memory watch's thread, "mem:<phase>": bench/lib.sh run_phased), on
#   - the same simulated flight (bench/plans/sim_memory.yaml over DATA_DIR/caliterra/images/IMG_9360.jpg, rendered
#     by the sim: source, nothing on disk) cut at 200, 2000 and 5000 frames: every phase's peak within the budget and
#     flat (phase peak at N frames <= 1.1 x the same phase's peak at 200 frames); the end of the flight's wall time
#     against the flight's duration at 1 frame/s;
#   - the full-resolution real flights (12 MP caliterra, brighton_beach): within the budget;
#   - flights of other frame sizes and aspects made from those (scaled to cover, centre-cropped, EXIF kept, by
#     uavm-reframe into a temporary folder): within the budget too, since it must hold for any frame size.
# Phases: flight; end solves (end_match end_load adjust lens refine radiometry); compose (outputs compose products).
# The program's own figures (report.json peak_rss_mib and memory.phases) are printed beside the outside sample.
# One markdown table (OUT_DIR/table.md and $RESULTS_DIR/memory-<date>-<hostname>.md).
#
# Environment:
#   BUDGET_MIB        memory budget passed to the program (default 256)
#   SIM_FRAMES        frames of the simulated runs (default "200 2000 5000"; the first is the reference; "" = none)
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
  sed -n '2,26p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
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
SIM_FRAMES=${SIM_FRAMES-200 2000 5000}
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
PHASE_ROWS=()
declare -A GROUP_PEAK GROUP_ANON
# group PHASE: the phase's group in the table.
group() {
  case $1 in
    start | flight) echo flight ;;
    end_match | end_load | adjust | lens | refine | radiometry) echo solves ;;
    *) echo compose ;;
  esac
}
# run NAME SOURCE [extra args]: one onboard run sampled by run_phased; a table row from report.json and a row per
# phase group from the outside samples.
run() {
  local name=$1 source=$2
  shift 2
  local dir=$OUT_DIR/$name
  rm -rf "$dir"
  log "$name: $source $*"
  # shellcheck disable=SC2086 # EXTRA_ARGS is a list of words
  run_phased "$dir" "$OURS_BIN" --source "$source" --out "$dir" --memory-budget "$BUDGET_MIB" "$@" ${EXTRA_ARGS:-}
  local report=$dir/report.json phase rss anon _n first last g end_start=""
  for g in flight solves compose; do GROUP_PEAK[$name.$g]=0 GROUP_ANON[$name.$g]=0; done
  while IFS=$'\t' read -r phase rss anon _n first last; do
    g=$(group "$phase")
    ((rss > GROUP_PEAK[$name.$g])) && GROUP_PEAK[$name.$g]=$rss
    ((anon > GROUP_ANON[$name.$g])) && GROUP_ANON[$name.$g]=$anon
    [[ $g != flight && -z $end_start ]] && end_start=$first
    PHASE_ROWS+=("| $name | $phase | $(fmt "$rss" 0 1024) | $(fmt "$anon" 0 1024) | $(jq -r --arg p "$phase" \
      '[.memory.phases[]? | select(.phase == $p) | .peak_rss_mib | floor] | first // "—"' "$report" 2>/dev/null) | \
$(awk -v a="$first" -v b="$last" 'BEGIN { printf "%.1f", b - a }') |")
  done <"$dir.phases.tsv"
  END_S[$name]=$(awk -v a="${end_start:-$W_WALL_S}" -v w="$W_WALL_S" 'BEGIN { printf "%.1f", w - a }')
  if ((W_RC != 0)) || [[ ! -s $report ]]; then
    ROWS+=("| $name | failed (exit $W_RC) | | | | | | | | | |")
    return 0
  fi
  ROWS+=("$(jq -r --arg name "$name" --arg peak "$(fmt "$W_PEAK_KB" 0 1024)" --arg anon "$(fmt "$W_PEAK_ANON_KB" 0 1024)" \
    --arg wall "$(fmt "$W_WALL_S" 1)" --arg endt "${END_S[$name]}" \
    --arg groups "$(fmt "${GROUP_PEAK[$name.flight]}" 0 1024) / $(fmt "${GROUP_PEAK[$name.solves]}" 0 1024) / $(fmt "${GROUP_PEAK[$name.compose]}" 0 1024)" '
    "| \($name) | \(.frames_in) | \(.registered) | \($wall) | \($endt) | \($peak) / \($anon) | \(.peak_rss_mib | floor) | " +
    "\($groups) | \(.memory.plan.end_correspondences) / \(.memory.spilled.end_points_per_edge) / " +
    "\(.memory.plan.refine_correspondences) | \(.open_fds.flight_start) / \(.open_fds.flight_end) | " +
    "\(.log.warnings) / \(.log.errors) | \(.holdout_rms_px * 1000 | round / 1000) |"' "$report" || echo "| $name | report unreadable |")")
}
declare -A END_S
SIM_NAMES=()
for n in $SIM_FRAMES; do
  run "sim_$n" "sim:$PLAN" --max-frames "$n" --no-tiff
  SIM_NAMES+=("sim_$n")
done
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

# Phase groups of each simulated run against the first (the reference length).
RATIO_ROWS=()
if ((${#SIM_NAMES[@]} > 1)); then
  ref=${SIM_NAMES[0]}
  for name in "${SIM_NAMES[@]:1}"; do
    cells=""
    for g in flight solves compose; do
      cells+=" $(awk -v a="${GROUP_PEAK[$name.$g]}" -v b="${GROUP_PEAK[$ref.$g]}" 'BEGIN { if (b > 0) printf "%.3f", a / b; else printf "—" }') /"
      cells+=" $(awk -v a="${GROUP_ANON[$name.$g]}" -v b="${GROUP_ANON[$ref.$g]}" 'BEGIN { if (b > 0) printf "%.3f", a / b; else printf "—" }') |"
    done
    frames=${name#sim_}
    RATIO_ROWS+=("| $name / $ref |$cells ${END_S[$name]} s = $(awk -v e="${END_S[$name]}" -v f="$frames" 'BEGIN { printf "%.1f", 100 * e / f }') % of a $frames s flight |")
  done
fi
{
  echo "Memory benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc), CPU: $(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -n 1), budget $BUDGET_MIB MiB"
  echo
  echo "| run | frames | registered | wall s | end of flight s | peak MiB outside: VmRSS / RssAnon | peak MiB report.json | phase group peaks MiB outside: flight / end solves / compose | end points cap / per edge / refine correspondences | open fds: flight start / end | log warnings / errors | held-out RMS px |"
  echo "|---|---:|---:|---:|---:|---|---:|---|---|---|---|---:|"
  printf '%s\n' "${ROWS[@]}"
  echo
  if ((${#RATIO_ROWS[@]} > 0)); then
    echo "Each phase group's peak against the same group at ${SIM_NAMES[0]#sim_} frames (target <= 1.1), VmRSS / RssAnon; the end of the flight's wall time:"
    echo
    echo "| runs | flight | end solves | compose | end of flight |"
    echo "|---|---|---|---|---|"
    printf '%s\n' "${RATIO_ROWS[@]}"
    echo
  fi
  echo "Every phase (outside: max VmRSS / RssAnon sampled every 50 ms; inside: report.json memory.phases, the program's MemoryWatch):"
  echo
  echo "| run | phase | VmRSS MiB outside | RssAnon MiB outside | VmRSS MiB inside | s |"
  echo "|---|---|---:|---:|---:|---:|"
  printf '%s\n' "${PHASE_ROWS[@]}"
  echo
  echo "sim runs: --no-tiff (the mosaic of a sim flight is not the point here); real runs write mosaic.tif. NAME_WxH runs: the real flight scaled to cover WxH and centre-cropped (FLIGHTS_SIZES). The longest sim run is also the soak: open file descriptors and log warnings must not grow with the flight."
} >"$OUT_DIR/table.md"
cp "$OUT_DIR/table.md" "$RESULTS_DIR/memory-$STAMP-$(hostname).md"
cat "$OUT_DIR/table.md"
