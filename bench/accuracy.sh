#!/usr/bin/env bash
# accuracy.sh DATA_DIR [OUT_DIR]
#
# Accuracy against the truth over many seeds and kinds of flight, and the false- and true-positive rates of the lens
# self-calibration's decision (issue 35; the short-flight gate of the CI tier is scripts/accuracy_gate.sh).
# Simulated 640x480 flights over DATA_DIR/caliterra/images/IMG_9360.jpg with yaw and altitude jitter, tilts, noise
# and blur (bench/plans/lens_jitter.yaml; lens_jitter_hard.yaml has stronger jitter and tilts): flights without a
# lens (any lens accepted is a false positive) and flights with a barrel lens of -5, -10 and -15 % at the half-diagonal
# (accepted, and a true RMS of at most 0.3 px with the session's lens, is a true positive). Each flight through
# uavmosaic-onboard with the defaults (and OURS_ARGS) and scored by uavmosaic-eval against the truth. One line per
# flight, then one table and the rates.
#
# Environment: HARD_SEEDS (default "11 .. 20", lens-free on lens_jitter_hard.yaml), EASY_SEEDS (default "21 .. 30",
# lens-free on lens_jitter.yaml), LENS_SEEDS (default "31 .. 40", barrels cycling -5/-10/-15 % on lens_jitter.yaml),
# UAVM_BUILD_DIR (default <repo>/build), OURS_ARGS (extra uavmosaic-onboard options) and RUN_TAG (suffix of each run's
# files: two settings compared on the same simulated flights, generated once in OUT_DIR; run them one after the other).
set -euo pipefail
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
[[ $# -ge 1 ]] || { sed -n '2,16p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2; }
DATA_DIR=$(cd "$1" && pwd)
OUT=${2:-$(mktemp -d "${TMPDIR:-/tmp}/uavm_accuracy.XXXXXX")}
mkdir -p "$OUT"
B=${UAVM_BUILD_DIR:-$REPO/build}
CANVAS=$DATA_DIR/caliterra/images/IMG_9360.jpg
read -r -a OURS_EXTRA <<<"${OURS_ARGS:-}"
# The lens for a share of the half-diagonal (the sim's focal is the frame width, 640, so the half-diagonal is at
# r = 0.625): k1 alone for -5 and -10 %. A k1-only -15 % (k1 = -0.384) folds before the recorded corners (r(1 + k1 r^2)
# peaks at 0.621 < 0.625: those pixels have no ideal point, no camera records them), so -15 % is k1 = -0.46 with
# k2 = 0.195 (-0.1499 at the half-diagonal, monotonic at every radius, within the sim's contraction bound).
lens_for() {
  case $1 in
    -0.15) echo "-0.46000 0.19500" ;;
    *) awk -v s="$1" 'BEGIN { printf "%.5f 0", s / (0.625 * 0.625) }' ;;
  esac
}
fp=0 n0=0 tp=0 n1=0
ROWS=()
one() {  # NAME PLAN SEED K1 [K2] -> prints a line; sets ACCEPTED and RMS
  local flight=$OUT/$1 n=$OUT/$1${RUN_TAG:-} ev=()
  { cat "$2"; echo "seed: $3"; echo "k1: $4"; echo "k2: ${5:-0}"; } >"$flight.yaml"
  [[ -f $flight/gt.csv ]] ||
    "$B/tools/uavmosaic-sim" --plan "$flight.yaml" --canvas "$CANVAS" --out "$flight" >"$flight.sim.log" 2>&1
  "$B/firmware_app/uavmosaic-onboard" --source "replay:$flight/images" --out "$n.out" --no-tiff "${OURS_EXTRA[@]}" \
    >"$n.log" 2>&1
  [[ -f $n.out/camera.yaml ]] && ev=(--session-camera "$n.out/camera.yaml")
  "$B/tools/uavmosaic-eval" --session "$n.out" --gt "$flight/gt.csv" --json "$n.eval.json" "${ev[@]}" --no-photometric \
    >"$n.eval.log" 2>&1
  RMS=$(jq -r '.rms_px' "$n.eval.json")
  ACCEPTED=0
  grep -q 'self-calibration accepted' "$n.log" && ACCEPTED=1
  local truth found
  truth=$(awk -v a="$4" -v b="${5:-0}" 'BEGIN { r2 = 0.625 * 0.625; printf "%+.4f", a * r2 + b * r2 * r2 }')
  found=$(jq -r '.lens.self_calibration | if .accepted then (.distortion_at_half_diagonal * 10000 | round / 10000 | tostring) else "—" end' \
    "$n.out/report.json" 2>/dev/null || echo "—")
  ROWS+=("| $1 | $(basename "$2" .yaml) | $truth | $([[ $ACCEPTED == 1 ]] && echo accepted || echo refused) | $found | $(printf '%.3f' "$RMS") |")
  # The decision, then the final estimate (the pairs matched again under the first, lens_calibration.rematch).
  echo "$1 (k1 $4 k2 ${5:-0}): true RMS $RMS px; $(grep -o 'lens self-calibration [a-z]*: .*edges)' "$n.log" | head -1)$(
    grep -o '; [0-9]* of [0-9]* pairs matched again.*' <(sed 's/lens: /; /' "$n.log") | head -1)"
}
for s in ${HARD_SEEDS-11 12 13 14 15 16 17 18 19 20}; do
  one "hard_${s}_none" "$SCRIPT_DIR/plans/lens_jitter_hard.yaml" "$s" 0
  n0=$((n0 + 1)) fp=$((fp + ACCEPTED))
done
for s in ${EASY_SEEDS-21 22 23 24 25 26 27 28 29 30}; do
  one "jitter_${s}_none" "$SCRIPT_DIR/plans/lens_jitter.yaml" "$s" 0
  n0=$((n0 + 1)) fp=$((fp + ACCEPTED))
done
shares=(-0.05 -0.10 -0.15)
i=0
for s in ${LENS_SEEDS-31 32 33 34 35 36 37 38 39 40}; do
  share=${shares[$((i % 3))]}
  i=$((i + 1))
  read -r k1 k2 <<<"$(lens_for "$share")"
  one "barrel_${s}_${share}" "$SCRIPT_DIR/plans/lens_jitter.yaml" "$s" "$k1" "$k2"
  n1=$((n1 + 1))
  ((ACCEPTED == 1)) && awk -v r="$RMS" 'BEGIN { exit !(r <= 0.3) }' && tp=$((tp + 1))
done
echo
echo "| flight | plan | lens at the half-diagonal | verdict | found | true RMS px |"
echo "|---|---|---:|---|---:|---:|"
printf '%s\n' "${ROWS[@]}"
echo
echo "false positives: $fp of $n0 flights without a lens; true positives (accepted, true RMS <= 0.3 px): $tp of $n1 flights with a barrel of -5 to -15 %"
