#!/usr/bin/env bash
# speed.sh DATA_DIR [OUT_DIR]
#
# Where the onboard program's time goes, flight by flight: the simulated flights of bench/plans (with ground truth)
# and the real full-resolution flights, each run RUNS times (default 1) with the program's defaults. Prints one
# markdown table: wall s, per-frame stage medians (decode, features, matching, adjust), (matching + adjust) /
# features, composite and product seconds, peak RSS against the budget, and the error (sims: grid error against
# the truth in original px; real: residual / held-out RMS from report.json). Medians over the runs.
# Also saved to OUT_DIR/table.md and $UAVM_RESULTS_DIR/speed-<date>.md.
#
# Environment:
#   FLIGHTS_SIM    default "sim_easy sim_hard sim_tilt1" ("" = none); sim flights are generated once in SIM_DIR
#   FLIGHTS_REAL   default "brighton_beach caliterra" ("" = none)
#   SIM_DIR        default /tmp/uavm-sim (kept between runs: generating a flight takes a while)
#   RUNS           runs per flight (default 1)
#   OURS_ARGS      extra uavmosaic-onboard options; "--replay-interval-ms N" replays at a camera's cadence (one photo
#                  every N ms, as in flight: stage medians without the backlog of an as-fast-as-possible replay)
#   UAVM_BUILD_DIR build tree (default <repo>/build); UAVM_RESULTS_DIR (default bench/results)
set -euo pipefail
export LC_ALL=C

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,18p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"

DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
OUT_DIR=${2:-/tmp/uavm-speed-$STAMP}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS_BIN=$BUILD/firmware_app/uavmosaic-onboard
SIM_BIN=$BUILD/tools/uavmosaic-sim
EVAL_BIN=$BUILD/tools/uavmosaic-eval
FLIGHTS_SIM=${FLIGHTS_SIM-sim_easy sim_hard sim_tilt1}
FLIGHTS_REAL=${FLIGHTS_REAL-brighton_beach caliterra}
SIM_DIR=${SIM_DIR:-/tmp/uavm-sim}
RUNS=${RUNS:-1}
read -r -a OURS_EXTRA <<<"${OURS_ARGS:-}"
CANVAS=$DATA_DIR/caliterra/images/IMG_9360.jpg
mkdir -p "$OUT_DIR" "$RESULTS_DIR" "$SIM_DIR"
log() { echo "[speed] $*" >&2; }
command -v jq >/dev/null 2>&1 || { log "jq missing (apt-get install jq)"; exit 1; }

median() { sort -g | awk '{ v[NR] = $1 } END { if (NR == 0) print ""; else print (NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2) }'; }

# One run of ours on IMAGES into DIR; appends "wall decode features matching adjust composite_s products_s rss budget
# err" to DIR/../runs.txt (err: eval RMS for sims, "residual/holdout" for real flights).
run_once() {
  local images=$1 dir=$2 gt=${3:-}
  rm -rf "$dir"
  run_watched "$dir" 0 0 "$OURS_BIN" --source "replay:$images" --out "$dir" "${OURS_EXTRA[@]}"
  ((W_RC == 0)) || { log "run failed: $(rc_text "$W_RC")"; return 1; }
  local err
  if [[ -n $gt ]]; then
    "$EVAL_BIN" --session "$dir" --gt "$gt" --json "$dir/eval.json" >"$dir/eval.log" 2>&1 || true
    err=$(jq -r '.rms_px // "-" | if type == "number" then (. * 1000 | round / 1000) else . end' "$dir/eval.json" \
      2>/dev/null || echo -)
  else
    err=$(jq -r '"\(.residual_rms_px * 1000 | round / 1000)/\(.holdout_rms_px * 1000 | round / 1000)"' "$dir/report.json")
  fi
  echo "$W_WALL_S $(jq -r '[.stages_ms.decode.median, .stages_ms.features.median, .stages_ms.matching.median,
      .stages_ms.adjust.median, (.composite_ms / 1000), ((.products.ms // 0) / 1000), .peak_rss_mib,
      .memory.budget_mib] | map(tostring) | join(" ")' "$dir/report.json") $err" >>"$(dirname "$dir")/runs.txt"
}

ROWS=()
row() {  # row LABEL RUNS_FILE
  local f=$2 n
  n=$(wc -l <"$f")
  local -a m
  for c in 1 2 3 4 5 6 7 8; do m[c]=$(awk -v c=$c '{ print $c }' "$f" | median); done
  local err
  err=$(awk '{ print $10 }' "$f" | sort | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }')
  local ratio
  ratio=$(awk -v a="${m[4]}" -v b="${m[5]}" -v f="${m[3]}" 'BEGIN { printf "%.2f", (a + b) / f }')
  ROWS+=("| $1 | $n | $(fmt "${m[1]}" 1) | $(fmt "${m[2]}" 0) | $(fmt "${m[3]}" 0) | $(fmt "${m[4]}" 0) | $(fmt "${m[5]}" 1) | $ratio | $(fmt "${m[6]}" 1) | $(fmt "${m[7]}" 1) | $(fmt "${m[8]}" 0) / $(awk '{ print $9; exit }' "$f") | $err |")
}

for name in $FLIGHTS_SIM; do
  flight=$SIM_DIR/$name
  if [[ ! -s $flight/gt.csv ]]; then
    log "$name: simulating"
    "$SIM_BIN" --plan "$SCRIPT_DIR/plans/$name.yaml" --canvas "$CANVAS" --out "$flight" >"$flight.sim.log" 2>&1 ||
      { log "$name: simulation failed ($flight.sim.log)"; continue; }
  fi
  rm -f "$OUT_DIR/$name/runs.txt"
  mkdir -p "$OUT_DIR/$name"
  for ((r = 1; r <= RUNS; r++)); do
    log "$name: run $r/$RUNS"
    run_once "$flight/images" "$OUT_DIR/$name/run$r" "$flight/gt.csv" || true
  done
  [[ -s $OUT_DIR/$name/runs.txt ]] && row "$name" "$OUT_DIR/$name/runs.txt"
done
for name in $FLIGHTS_REAL; do
  rm -f "$OUT_DIR/$name/runs.txt"
  mkdir -p "$OUT_DIR/$name"
  for ((r = 1; r <= RUNS; r++)); do
    log "$name: run $r/$RUNS"
    run_once "$DATA_DIR/$name/images" "$OUT_DIR/$name/run$r" || true
  done
  [[ -s $OUT_DIR/$name/runs.txt ]] && row "$name (real)" "$OUT_DIR/$name/runs.txt"
done

{
  echo "uavmosaic speed, $(date -u '+%Y-%m-%d %H:%M UTC'), $(git -C "$REPO" rev-parse --short HEAD 2>/dev/null || echo '?'), nproc $(nproc), CPU: $(cpu_model)${OURS_ARGS:+, options: $OURS_ARGS}"
  echo
  echo "| flight | runs | wall s | decode ms | features ms | matching ms | adjust ms | (matching + adjust) / features | composite s | products s | peak RSS / budget MiB | error |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
  printf '%s\n' "${ROWS[@]}"
  echo
  echo "Stage columns: medians over the flight's frames (report.json stages_ms), then the median over the runs. error: sims = uavmosaic-eval grid RMS against the truth, original px; real = residual / held-out RMS, working px (report.json)."
} | tee "$OUT_DIR/table.md" >"$RESULTS_DIR/speed-$STAMP.md"
cat "$OUT_DIR/table.md"
