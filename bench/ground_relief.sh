#!/usr/bin/env bash
# ground_relief.sh [OUT_DIR]
#
# The ground tool's map against the truth of a synthetic survey over relief (tools/relief_flight.h: 8 buildings of
# 8-25 m and 20 trees on a slope, 1000x750 frames at 70 m, GPS 1.5 m, a mild lens): uavmosaic-relief fly, then
# uavmosaic-onboard (replay, positions from geo.txt) and uavmosaic-ground --render-previews on the session, each under
# the bench's watchdog (peak VmRSS sampled from /proc), again with the surveyed targets (every third a checkpoint) and
# with them without heights, then uavmosaic-relief compare on the ground tool's ortho.tif, dsm.tif and dtm.tif (with
# and without GCPs) and on the onboard mosaic.tif; with SEAMS_ANYWHERE=1 the GCP run again with each ortho cell from
# its most nadir view (--ortho-seams-anywhere), for the seams through standing objects with and without keeping them
# off. Prints Markdown tables; everything stays in OUT_DIR.
#
# Environment: UAVM_BUILD_DIR (default <repo>/build), THREADS (default 2), SEED (default 1), RELIEF_ARGS (more
# `uavmosaic-relief fly` options, e.g. "--buildings 12 --gps-sigma 3").
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -gt 1 || ${1:-} == -h || ${1:-} == --help ]]; then
  sed -n '2,11p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"
OUT=${1:-$(mktemp -d /tmp/ground_relief.XXXXXX)}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
THREADS=${THREADS:-2}
for b in firmware_app/uavmosaic-onboard ground_app/uavmosaic-ground tools/uavmosaic-relief; do
  [[ -x $BUILD/$b ]] || { echo "missing $BUILD/$b (scripts/build.sh)" >&2; exit 2; }
done
mkdir -p "$OUT"
rm -rf "$OUT/flight" "$OUT/session" "$OUT/ground"
# shellcheck disable=SC2086 # RELIEF_ARGS is a list of words
"$BUILD/tools/uavmosaic-relief" fly --out "$OUT/flight" --seed "${SEED:-1}" ${RELIEF_ARGS:-} >"$OUT/flight.json"
run_watched "$OUT/onboard" 0 0 "$BUILD/firmware_app/uavmosaic-onboard" --source "replay:$OUT/flight/images" \
  --telemetry "geo:$OUT/flight/geo.txt" --out "$OUT/session" --log-level warn
((W_RC == 0)) || { echo "onboard: exit $W_RC" >&2; tail -5 "$OUT/onboard.stderr" >&2; exit 1; }
ONBOARD_S=$W_WALL_S ONBOARD_MIB=$(peak_mib)
run_watched "$OUT/ground" 0 0 "$BUILD/ground_app/uavmosaic-ground" "$OUT/session" --out "$OUT/ground" \
  --threads "$THREADS" --render-previews
((W_RC == 0)) || { echo "ground: exit $W_RC" >&2; tail -5 "$OUT/ground.stderr" >&2; exit 1; }
GROUND_S=$W_WALL_S GROUND_MIB=$(peak_mib)
# The same with the surveyed targets: every third a checkpoint; then the targets without heights (sparse only: the
# checkpoints are what it measures).
CHECKS=$(jq -r '.checkpoints | join(",")' "$OUT/flight.json")
run_watched "$OUT/ground_gcp" 0 0 "$BUILD/ground_app/uavmosaic-ground" "$OUT/session" --out "$OUT/ground_gcp" \
  --threads "$THREADS" --gcp "$OUT/flight/gcp_list.txt" --checkpoints "$CHECKS"
((W_RC == 0)) || { echo "ground with GCPs: exit $W_RC" >&2; tail -5 "$OUT/ground_gcp.stderr" >&2; exit 1; }
if [[ ${SEAMS_ANYWHERE:-0} == 1 ]]; then
  run_watched "$OUT/ground_gcp_anywhere" 0 0 "$BUILD/ground_app/uavmosaic-ground" "$OUT/session" \
    --out "$OUT/ground_gcp_anywhere" --threads "$THREADS" --gcp "$OUT/flight/gcp_list.txt" --checkpoints "$CHECKS" \
    --ortho-seams-anywhere
  ((W_RC == 0)) || { echo "ground with GCPs, seams anywhere: exit $W_RC" >&2; exit 1; }
  "$BUILD/tools/uavmosaic-relief" compare "$OUT/flight" --ortho "$OUT/ground_gcp_anywhere/ortho.tif" \
    >"$OUT/compare_ground_gcp_anywhere.json"
fi
run_watched "$OUT/ground_gcp_flat" 0 0 "$BUILD/ground_app/uavmosaic-ground" "$OUT/session" \
  --out "$OUT/ground_gcp_flat" --threads "$THREADS" --gcp "$OUT/flight/gcp_list_no_heights.txt" \
  --checkpoints "$CHECKS" --no-dense --no-ortho
((W_RC == 0)) || { echo "ground with GCPs without heights: exit $W_RC" >&2; exit 1; }
"$BUILD/tools/uavmosaic-relief" compare "$OUT/flight" --ortho "$OUT/ground_gcp/ortho.tif" --dsm "$OUT/ground_gcp/dsm.tif" \
  --dsm-filled "$OUT/ground_gcp/dsm_filled.tif" --dtm "$OUT/ground_gcp/dtm.tif" >"$OUT/compare_ground_gcp.json"
"$BUILD/tools/uavmosaic-relief" compare "$OUT/flight" --ortho "$OUT/ground/ortho.tif" --dsm "$OUT/ground/dsm.tif" \
  --dsm-filled "$OUT/ground/dsm_filled.tif" --dtm "$OUT/ground/dtm.tif" >"$OUT/compare_ground.json"
"$BUILD/tools/uavmosaic-relief" compare "$OUT/flight" --ortho "$OUT/session/mosaic.tif" >"$OUT/compare_onboard.json"
python3 - "$OUT" "$ONBOARD_S" "$ONBOARD_MIB" "$GROUND_S" "$GROUND_MIB" <<'PY'
import json, sys
out, onboard_s, onboard_mib, ground_s, ground_mib = sys.argv[1:]
fly = json.load(open(f"{out}/flight.json"))
g = json.load(open(f"{out}/compare_ground.json"))
o = json.load(open(f"{out}/compare_onboard.json"))
gg = json.load(open(f"{out}/compare_ground_gcp.json"))
summary = json.load(open(f"{out}/ground/summary.json"))
print(f"Synthetic relief survey: {fly['frames']} frames {fly['camera']['width']}x{fly['camera']['height']}, "
      f"GSD {fly['gsd_m']:.3f} m, {fly['scene']['buildings']} buildings, {fly['scene']['trees']} trees")
print(f"onboard {onboard_s} s, peak {onboard_mib} MiB; ground {ground_s} s, peak {ground_mib} MiB "
      f"(VmRSS sampled from /proc); ground BA {summary['ba_rms_after_px']:.3f} px, {summary['dense_points']} dense points")
print()
print("| orthophoto against the truth (patch phase correlation, GSD) | all: RMS / median | ground | roofs | crowns | "
      "relative (median shift out): all RMS / median | offset (x, y) | patches |")
print("|---|---|---|---|---|---|---|---|")
rows = [("ground tool ortho.tif", g["ortho"]), ("ground tool ortho.tif with GCPs", gg["ortho"])]
try:
    rows.append(("the same, seams anywhere (`--ortho-seams-anywhere`)",
                 json.load(open(f"{out}/compare_ground_gcp_anywhere.json"))["ortho"]))
except FileNotFoundError:
    pass
rows.append(("onboard mosaic.tif", o["ortho"]))
for name, r in rows:
    cls = lambda k: f"{r[k]['rms_gsd']:.2f} / {r[k]['median_gsd']:.2f} ({r[k]['patches']})"
    print(f"| {name} | {cls('all')} | {cls('ground')} | {cls('roofs')} | {cls('crowns')} | "
          f"{r['all']['relative_rms_gsd']:.2f} / {r['all']['relative_median_gsd']:.2f} | "
          f"{r['offset_gsd'][0]:.2f}, {r['offset_gsd'][1]:.2f} | {r['patches']} ({r['unmatched']} unmatched) |")
print()
print("| seams (summary.json ortho) | standing objects (taken whole) | seam cells | of which cutting a standing object |")
print("|---|---|---|---|")
for name in ("ground", "ground_gcp", "ground_gcp_anywhere"):
    try:
        so = json.load(open(f"{out}/{name}/summary.json"))["ortho"]
    except FileNotFoundError:
        continue
    print(f"| {name} | {so.get('standing_objects')} ({so.get('standing_objects_taken_whole')}) | "
          f"{so.get('seam_cells')} | {so.get('seam_cells_on_standing_objects')} |")
print()
print("| heights against the truth (away from 1 m of edges), GSD RMS (after the median bias) | measured | surfaces | "
      "ground | roofs / under buildings | crowns / under trees | bias m |")
print("|---|---|---|---|---|---|---|")
for name, r in (("dsm", g["dsm"]), ("dtm", g["dtm"]), ("dsm with GCPs", gg["dsm"]), ("dtm with GCPs", gg["dtm"])):
    cls = lambda k: f"{r[k]['rms_gsd']:.2f} ({r[k]['rms_after_bias_gsd']:.2f})"
    print(f"| {name} | {r['measured_fraction']:.3f} | {cls('surfaces')} | {cls('ground')} | {cls('roofs')} | "
          f"{cls('crowns')} | {r['bias_m']:.3f} |")
print()
print("| GCPs (2 cm survey, 0.5 px clicks) | control points | control RMS x / y / z m | checkpoints | "
      "checkpoint RMS x / y / z m | checkpoint horizontal GSD |")
print("|---|---|---|---|---|---|")
gsd = fly["gsd_m"]
for name in ("ground_gcp", "ground_gcp_flat"):
    gcp = json.load(open(f"{out}/{name}/summary.json"))["gcp"]
    c, k = gcp["control_rms"], gcp["checkpoint_rms"]
    z = lambda r: "—" if r["z_m"] is None else f"{r['z_m']:.3f}"
    label = "with heights" if name == "ground_gcp" else "without heights (horizontal only)"
    print(f"| {label} | {c['points']} | {c['x_m']:.3f} / {c['y_m']:.3f} / {z(c)} | {k['points']} | "
          f"{k['x_m']:.3f} / {k['y_m']:.3f} / {z(k)} | {(k['x_m'] ** 2 + k['y_m'] ** 2) ** 0.5 / gsd:.2f} |")
PY
