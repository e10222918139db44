#!/usr/bin/env bash
# gate_seeds.sh [--base ONBOARD] [--flights "NAMES"] [--seeds "SEEDS"] OUT_DIR
#
# The accuracy gate's flights (scripts/accuracy/flights.sh) over many seeds: each flight kind flown with each seed
# instead of its own, mosaicked by this build's uavmosaic-onboard (and by --base, another build's, on the same
# simulated flights) and scored against the truth as the gate does. One seed is one draw: a flight's true RMS moves
# by tens of per cent under changes of no accuracy consequence (float rounding, a keypoint more or less), so a change
# is judged on the kinds' means and the median of the per-seed ratios, not on the gate's one seed.
# Prints per seed and per kind (mean, median, median ratio new/base, seeds where new is worse); also OUT_DIR/table.md.
#
# Defaults: --flights "easy jitter_tilt barrel_jitter", --seeds "1 .. 16". Environment: UAVM_BUILD_DIR.
set -euo pipefail
export LC_ALL=C
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${UAVM_BUILD_DIR:-$ROOT/build}"
BASE=""
KINDS="easy jitter_tilt barrel_jitter"
SEEDS="$(seq -s ' ' 1 16)"
while [[ $# -gt 1 ]]; do
  case $1 in
    --base) BASE=$2 ;;
    --flights) KINDS=$2 ;;
    --seeds) SEEDS=$2 ;;
    *) sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2 ;;
  esac
  shift 2
done
[[ $# -eq 1 && $1 != -* ]] || { sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2; }
OUT=$1
mkdir -p "$OUT"
command -v jq >/dev/null || { echo "gate_seeds: jq missing" >&2; exit 1; }
# shellcheck source=scripts/accuracy/flights.sh
source "$ROOT/scripts/accuracy/flights.sh"

# rms BIN FLIGHT_DIR NAME: true RMS of BIN's session of the flight ("failed" when a step fails).
rms() {
  local s="$2/$3"
  rm -rf "$s"
  if "$1" --source "replay:$2/flight/images" --out "$s" --no-products --log-level warn >"$s.log" 2>&1 &&
    "$BUILD/tools/uavmosaic-eval" --session "$s" --gt "$2/flight/gt.csv" --no-photometric \
      --session-camera "$s/camera.yaml" --json "$s.json" >/dev/null 2>&1; then
    jq -r '.rms_px' "$s.json"
  else
    echo failed
  fi
}

: >"$OUT/runs.tsv"
for kind in $KINDS; do
  [[ -n ${PLAN[$kind]+x} ]] || { echo "gate_seeds: no flight $kind in scripts/accuracy/flights.sh" >&2; exit 2; }
  for seed in $SEEDS; do
    dir="$OUT/$kind-$seed"
    mkdir -p "$dir"
    flight_plan "$kind" "$seed" >"$dir/plan.yaml"
    "$BUILD/tools/uavmosaic-sim" --plan "$dir/plan.yaml" --canvas "$FLIGHT_CANVAS" --out "$dir/flight" >"$dir/sim.log" 2>&1
    new=$(rms "$BUILD/firmware_app/uavmosaic-onboard" "$dir" new)
    base=-
    [[ -z $BASE ]] || base=$(rms "$BASE" "$dir" base)
    printf '%s\t%s\t%s\t%s\n' "$kind" "$seed" "$base" "$new" | tee -a "$OUT/runs.tsv"
  done
done
{
  echo "| flight | seeds | base mean | new mean | base median | new median | median ratio new/base | new worse |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|"
  for kind in $KINDS; do
    awk -F'\t' -v k="$kind" '
      function median(a, n,   i, j, t) {
        for (i = 2; i <= n; i++) for (j = i; j > 1 && a[j - 1] > a[j]; j--) { t = a[j]; a[j] = a[j - 1]; a[j - 1] = t }
        return n % 2 ? a[(n + 1) / 2] : (a[n / 2] + a[n / 2 + 1]) / 2
      }
      $1 == k && $4 != "failed" {
        n++; nw[n] = $4; sn += $4
        if ($3 != "-" && $3 != "failed") { m++; b[m] = $3; sb += $3; r[m] = $4 / $3; worse += $4 > $3 }
      }
      END {
        if (m) printf "| %s | %d | %.4f | %.4f | %.4f | %.4f | %.3f | %d |\n", k, n, sb / m, sn / n, median(b, m), median(nw, n), median(r, m), worse
        else printf "| %s | %d | - | %.4f | - | %.4f | - | - |\n", k, n, sn / n, median(nw, n)
      }' "$OUT/runs.tsv"
  done
} | tee "$OUT/table.md"
