#!/usr/bin/env bash
# accuracy_gate.sh [--record]: the accuracy gate of the CI tier. Short simulated flights of different kinds, with
# ground truth, over the bundled photograph (tests/data/caliterra_small/images/IMG_9360.jpg): each is simulated
# (uavmosaic-sim), mosaicked (uavmosaic-onboard, defaults) and scored against its truth (uavmosaic-eval: RMS of the
# frames' map error in frame pixels, through the true lens and the session's own). Each flight's true RMS is compared with the figure recorded in
# scripts/accuracy/records.tsv: more than 10 % above it (and more than 0.01 px: a floor for the near-perfect flights)
# fails the run. The table is printed either way. --record writes the figures measured now as the new records (after a
# change that improved them; a worse figure is never recorded silently: the diff shows it).
#
# Environment: UAVM_BUILD_DIR (default <repo>/build); UAVM_ACCURACY_DIR (work folder, default a temporary one);
# UAVM_ACCURACY_ARGS (more uavmosaic-onboard options, e.g. a deliberate regression to see the gate fail).
set -euo pipefail
export LC_ALL=C
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${UAVM_BUILD_DIR:-$ROOT/build}"
RECORDS="$ROOT/scripts/accuracy/records.tsv"
RECORD=0
[[ ${1:-} == --record ]] && RECORD=1
WORK="${UAVM_ACCURACY_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/uavm-accuracy.XXXXXX")}"
[[ -n ${UAVM_ACCURACY_DIR:-} ]] || trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK"
read -r -a EXTRA <<<"${UAVM_ACCURACY_ARGS:-}"

# The flights (FLIGHTS, PLAN, COMMON): scripts/accuracy/flights.sh, shared with bench/gate_seeds.sh.
# shellcheck source=scripts/accuracy/flights.sh
source "$ROOT/scripts/accuracy/flights.sh"
status=0
ROWS=()
NEW=()
for name in "${FLIGHTS[@]}"; do
  dir="$WORK/$name"
  rm -rf "$dir"
  mkdir -p "$dir"
  flight_plan "$name" >"$dir/plan.yaml"
  rms="failed"
  if "$BUILD/tools/uavmosaic-sim" --plan "$dir/plan.yaml" --canvas "$FLIGHT_CANVAS" --out "$dir/flight" >"$dir/sim.log" 2>&1 &&
    "$BUILD/firmware_app/uavmosaic-onboard" --source "replay:$dir/flight/images" --out "$dir/session" --no-products \
      --log-level warn "${EXTRA[@]}" >"$dir/onboard.log" 2>&1 &&
    "$BUILD/tools/uavmosaic-eval" --session "$dir/session" --gt "$dir/flight/gt.csv" --no-photometric \
      --session-camera "$dir/session/camera.yaml" --json "$dir/eval.json" >"$dir/eval.log" 2>&1; then
    rms=$(jq -r '.rms_px' "$dir/eval.json")
  fi
  frames=$(jq -r '"\(.registered)/\(.frames)"' "$dir/eval.json" 2>/dev/null || echo "—")
  lens=$(jq -r '.lens.self_calibration.accepted | if . == null then "—" else tostring end' "$dir/session/report.json" 2>/dev/null || echo "—")
  recorded=$(awk -F'\t' -v n="$name" '$1 == n { print $2 }' "$RECORDS" 2>/dev/null || true)
  verdict="ok"
  if [[ $rms == failed ]]; then
    verdict="FAILED (see $dir)"
    status=1
  elif [[ -z $recorded ]]; then
    verdict="no record"
  elif awk -v m="$rms" -v r="$recorded" 'BEGIN { exit !(m > 1.1 * r && m > r + 0.01) }'; then
    verdict="REGRESSION (> 10 % and > 0.01 px above the record)"
    status=1
  fi
  ROWS+=("| $name | $frames | $(printf '%.4f' "$rms" 2>/dev/null || echo "$rms") | ${recorded:-—} | $lens | $verdict |")
  NEW+=("$name	$rms	$(date +%Y-%m-%d): $frames frames registered")
done
echo "Accuracy gate: true RMS (frame px) of short simulated flights against scripts/accuracy/records.tsv"
echo
echo "| flight | registered | true RMS px | recorded | lens accepted | verdict |"
echo "|---|---|---:|---:|---|---|"
printf '%s\n' "${ROWS[@]}"
if ((RECORD)); then
  { echo "# flight	true RMS px	when (scripts/accuracy_gate.sh --record)"; printf '%s\n' "${NEW[@]}"; } >"$RECORDS"
  echo "records written to $RECORDS"
  exit 0
fi
exit "$status"
