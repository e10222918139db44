#!/usr/bin/env bash
# bench/identical.sh OUT.tsv: the outputs a redesign must not change, as checksums. Runs uavmosaic-onboard (defaults,
# products) on the bundled flights, the accuracy gate (its simulated flights, --no-products), two bench sims, a flight with
# telemetry from a .tlog, one with the live tile pyramid, and one interrupted after 8 frames then resumed; writes one line per session file that
# must stay byte-identical (transforms.csv, frames.csv but its capture times, camera.yaml) with its sha256. Compare two runs with `diff`.
#
# Environment: UAVM_BUILD_DIR (default <repo>/build); UAVM_IDENTICAL_DIR (work folder kept, default a temporary one).
set -euo pipefail
export LC_ALL=C
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${UAVM_BUILD_DIR:-$ROOT/build}"
OUT="${1:?usage: bench/identical.sh OUT.tsv}"
WORK="${UAVM_IDENTICAL_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/uavm-identical.XXXXXX")}"
[[ -n ${UAVM_IDENTICAL_DIR:-} ]] || trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK"
ONBOARD="$BUILD/firmware_app/uavmosaic-onboard"
SIM="$BUILD/tools/uavmosaic-sim"
CANVAS="$ROOT/tests/data/caliterra_small/images/IMG_9360.jpg"

# sim NAME PLAN_TEXT: a simulated flight over the bundled photograph, in $WORK/NAME/flight.
sim() {
  mkdir -p "$WORK/$1"
  printf '%s\n' "$2" >"$WORK/$1/plan.yaml"
  "$SIM" --plan "$WORK/$1/plan.yaml" --canvas "$CANVAS" --out "$WORK/$1/flight" >"$WORK/$1/sim.log" 2>&1
}
# onboard NAME SOURCE [ARGS...]: a session in $WORK/NAME/session.
onboard() {
  local name=$1 source=$2
  shift 2
  mkdir -p "$WORK/$name"
  "$ONBOARD" --source "$source" --out "$WORK/$name/session" --log-level warn "$@" >>"$WORK/$name/onboard.log" 2>&1 ||
    echo "$name: uavmosaic-onboard exited $? (see $WORK/$name/onboard.log)" >&2
}

# The accuracy gate's five simulated flights, flown and mosaicked by the gate itself (its plans are written once, there);
# their sessions are checksummed below like the others.
UAVM_BUILD_DIR="$BUILD" UAVM_ACCURACY_DIR="$WORK/gate" bash "$ROOT/scripts/accuracy_gate.sh" >"$WORK/gate.log" 2>&1 ||
  echo "the accuracy gate failed (see $WORK/gate.log)" >&2
for name in easy jitter_tilt barrel_lens water_gps; do ln -sfn "$WORK/gate/$name" "$WORK/$name"; done
sim vignetting "$(grep -v '^#' "$ROOT/bench/plans/radiometry_vignetting.yaml")"
sim tilt1 "$(grep -v '^#' "$ROOT/bench/plans/sim_tilt1.yaml" | sed 's/^strips: 0/strips: 2/; s/^strip_length: 0/strip_length: 1800/')"

onboard brighton replay:"$ROOT/tests/data/brighton_beach_small/images"
onboard caliterra replay:"$ROOT/tests/data/caliterra_small/images"
for name in vignetting tilt1; do
  onboard "$name" replay:"$WORK/$name/flight/images"
done
tlog=$(find "$WORK/water_gps/flight" -name '*.tlog' | head -1)
onboard water_tlog replay:"$WORK/water_gps/flight/images" --telemetry "tlog:$tlog"
printf 'live_tiles:\n  enabled: true\n' >"$WORK/live_tiles.yaml"
onboard live_tiles replay:"$ROOT/tests/data/brighton_beach_small/images" --config "$WORK/live_tiles.yaml"
onboard resumed replay:"$ROOT/tests/data/brighton_beach_small/images" --max-frames 8
onboard resumed replay:"$ROOT/tests/data/brighton_beach_small/images" --resume

: >"$OUT"
for name in brighton caliterra easy jitter_tilt barrel_lens vignetting tilt1 water_gps water_tlog live_tiles resumed; do
  for file in transforms.csv frames.csv camera.yaml; do
    path="$WORK/$name/session/$file"
    # frames.csv's timestamp_ns is the capture clock's (a replay's: when the file was read): not compared.
    sum=$([[ -f $path ]] && awk -F, -v OFS=, '{ if (FILENAME ~ /frames.csv$/) $6 = ""; print }' "$path" |
      sha256sum | cut -c1-16 || echo missing)
    printf '%s\t%s\t%s\n' "$name" "$file" "$sum" >>"$OUT"
  done
  reg=$(jq -r '"\(.registration.registered // .registered)/\(.frames_in // .frames)"' "$WORK/$name/session/report.json" 2>/dev/null || echo "-")
  printf '%s\t%s\t%s\n' "$name" "registered" "$reg" >>"$OUT"
done
cat "$OUT"
