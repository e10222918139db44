#!/usr/bin/env bash
# sift_cost.sh DATA_DIR [OUT_DIR]
#
# Detection alone (issue 40: "detection at a third of its cost"): on every frame of each flight, our SIFT with the
# product's defaults against OpenCV 4.6's SIFT in the 3-band plan it replaced, alternately, nothing else running
# (build/bench/uavm-sift-cost). The flights: bench/speed.sh's simulated ones (generated there, in SIM_DIR) and the real
# full-resolution ones. Prints one markdown table (medians over the frames of the per-frame medians over REPEAT runs):
# wall and CPU ms of each and their ratios. Also saved to OUT_DIR/table.md and $UAVM_RESULTS_DIR/sift-cost-<date>.md.
# bench/speed.sh gives the same stage inside the flight, where it shares two cores with the decode and the
# registration.
#
# Environment: FLIGHTS_SIM (default "sim_easy sim_hard sim_tilt1"), FLIGHTS_REAL (default "brighton_beach
# caliterra"), SIM_DIR (default /tmp/uavm-sim), FRAMES (default 0 = all), REPEAT (default 3), PAUSE_MS (idle before
# each detection, a camera's cadence: default 0), UAVM_BUILD_DIR, UAVM_RESULTS_DIR.
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"
DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
OUT_DIR=${2:-/tmp/uavm-sift-cost-$STAMP}
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
BIN=$BUILD/bench/uavm-sift-cost
SIM_BIN=$BUILD/tools/uavmosaic-sim
FLIGHTS_SIM=${FLIGHTS_SIM-sim_easy sim_hard sim_tilt1}
FLIGHTS_REAL=${FLIGHTS_REAL-brighton_beach caliterra}
SIM_DIR=${SIM_DIR:-/tmp/uavm-sim}
CANVAS=$DATA_DIR/caliterra/images/IMG_9360.jpg
mkdir -p "$OUT_DIR" "$RESULTS_DIR" "$SIM_DIR"
log() { echo "[sift-cost] $*" >&2; }
[[ -x $BIN ]] || { log "missing $BIN (build the bench targets)"; exit 1; }

ROWS=()
for name in $FLIGHTS_SIM; do
  flight=$SIM_DIR/$name
  if [[ ! -s $flight/gt.csv ]]; then
    log "$name: simulating"
    "$SIM_BIN" --plan "$SCRIPT_DIR/plans/$name.yaml" --canvas "$CANVAS" --out "$flight" >"$flight.sim.log" 2>&1 ||
      { log "$name: simulation failed ($flight.sim.log)"; continue; }
  fi
  log "$name"
  ROWS+=("$("$BIN" --images "$flight/images" --frames "${FRAMES:-0}" --repeat "${REPEAT:-3}" \
    --pause-ms "${PAUSE_MS:-0}" --label "$name")")
done
for name in $FLIGHTS_REAL; do
  log "$name"
  ROWS+=("$("$BIN" --images "$DATA_DIR/$name/images" --frames "${FRAMES:-0}" --repeat "${REPEAT:-3}" \
    --pause-ms "${PAUSE_MS:-0}" --label "$name (real)")")
done
{
  echo "uavmosaic detection alone, $(date -u '+%Y-%m-%d %H:%M UTC'), $(git -C "$REPO" rev-parse --short HEAD 2>/dev/null || echo '?'), nproc $(nproc), CPU: $(cpu_model)"
  echo
  echo "| flight | frames | ours wall ms | OpenCV 3 bands wall ms | ratio | ours CPU ms | OpenCV CPU ms | ratio | keypoints ours / OpenCV |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|---|"
  printf '%s\n' "${ROWS[@]}"
  echo
  echo "Per frame the median of ${REPEAT:-3} runs of each, alternately; per flight the median over its frames. CPU: the process's user + system time (getrusage), both pool threads."
} | tee "$OUT_DIR/table.md" >"$RESULTS_DIR/sift-cost-$STAMP.md"
cat "$OUT_DIR/table.md"
