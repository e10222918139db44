#!/usr/bin/env bash
# ground_vs_colmap.sh DATA_DIR [OUT_DIR]
#
# The ground tool against COLMAP 3.8 (Debian's CPU build, sparse only) on the same frames, one after the other, in
# one run: for each flight (default brighton_beach at full resolution, then caliterra),
#   COLMAP:    feature_extractor (CPU SIFT, one OPENCV camera) -> spatial_matcher (EXIF GPS, COLMAP_NEIGHBORS nearest,
#              as suits a survey grid) -> mapper; the largest model is kept;
#   uavmosaic: uavmosaic-onboard into a session (what the drone writes in flight), then uavmosaic-ground --no-dense.
# Both models are aligned to the EXIF GPS camera positions (E, N in UTM, relative altitude) by COLMAP's model_aligner
# and measured by the same code (bench/colmap_compare.py). Prints one table per flight and keeps them in
# bench/results/ground-vs-colmap-<stamp>.md.
#
# Environment: UAVM_BUILD_DIR (default <repo>/build), THREADS (2), FLIGHTS ("brighton_beach caliterra"),
#              COLMAP_NEIGHBORS (10), GROUND_ARGS (extra uavmosaic-ground options), UAVM_RESULTS_DIR.
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,16p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
DATA=$1
OUT=${2:-$(mktemp -d /tmp/ground_vs_colmap.XXXXXX)}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
RESULTS=${UAVM_RESULTS_DIR:-$REPO/bench/results}
THREADS=${THREADS:-2}
NEIGHBORS=${COLMAP_NEIGHBORS:-10}
FLIGHTS=${FLIGHTS:-brighton_beach caliterra}
ONBOARD=$BUILD/firmware_app/uavmosaic-onboard
GROUND=$BUILD/ground_app/uavmosaic-ground
PY=/usr/bin/python3  # Debian's, with numpy and GDAL's bindings
for b in "$ONBOARD" "$GROUND"; do [[ -x $b ]] || { echo "missing $b (build it first)" >&2; exit 2; }; done
command -v colmap >/dev/null || { echo "colmap not found (apt-get install colmap)" >&2; exit 2; }
mkdir -p "$OUT" "$RESULTS"

# /usr/bin/time -v figures.
peak_mib() { awk -F: '/Maximum resident set size/ {printf "%.0f", $2/1024}' "$1"; }
wall_s() { awk '/Elapsed \(wall clock\)/ {n=split($NF,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; printf "%.1f", s}' "$1"; }
timed() { # timed NAME CMD...: runs CMD under /usr/bin/time -v, output to $W/NAME.{log,time}
  local name=$1
  shift
  /usr/bin/time -v "$@" >"$W/$name.log" 2>&1 || { echo "$name failed: see $W/$name.log" >&2; tail -5 "$W/$name.log" >&2; return 1; }
  grep -E "Maximum resident|Elapsed" "$W/$name.log" >"$W/$name.time"
}
sum_wall() { local s=0 f; for f in "$@"; do s=$(awk -v a="$s" -v b="$(wall_s "$f")" 'BEGIN{printf "%.1f", a+b}'); done; echo "$s"; }
max_peak() { local m=0 f v; for f in "$@"; do v=$(peak_mib "$f"); ((v > m)) && m=$v; done; echo "$m"; }

# GPS reference of a session (name easting northing relative-altitude), from its frames.csv; names from COLUMN
# (filename: the originals, as COLMAP names them; stored_file: uavmosaic's copies, as our model names them).
gps_ref() {
  "$PY" - "$1/frames.csv" "$2" <<'EOF'
import csv, sys
from osgeo import osr
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r.get("latitude_deg") and r.get("longitude_deg")]
if rows:
    lat0, lon0 = float(rows[0]["latitude_deg"]), float(rows[0]["longitude_deg"])
    epsg = (32600 if lat0 >= 0 else 32700) + int((lon0 + 180) // 6) % 60 + 1
    src, dst = osr.SpatialReference(), osr.SpatialReference()
    src.ImportFromEPSG(4326); dst.ImportFromEPSG(epsg)
    for s in (src, dst): s.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    tr = osr.CoordinateTransformation(src, dst)
    for r in rows:
        x, y, _ = tr.TransformPoint(float(r["longitude_deg"]), float(r["latitude_deg"]))
        z = r.get("relative_altitude_m") or r.get("altitude_m") or "0"
        print(r[sys.argv[2]].split("/")[-1], f"{x:.3f}", f"{y:.3f}", z)
EOF
}

# COLMAP's largest model (most images) of a mapper output directory.
largest_model() {
  local best="" n=0 d k
  for d in "$1"/*/; do
    [[ -f $d/images.bin || -f $d/images.txt ]] || continue
    k=$(colmap model_analyzer --path "$d" 2>&1 | awk '/Registered images:/ {print $NF}')
    if ((${k:-0} > n)); then n=$k best=$d; fi
  done
  echo "${best%/}"
}

aligned_txt() { # aligned_txt MODEL REF OUTDIR [--ref_is_gps 0 ...]: model_aligner then a text copy in OUTDIR
  mkdir -p "$3/aligned" "$3/txt"
  colmap model_aligner --input_path "$1" --output_path "$3/aligned" --ref_images_path "$2" --ref_is_gps 0 \
    --alignment_type custom --robust_alignment 1 --robust_alignment_max_error 10 >"$3/aligner.log" 2>&1 ||
    cp -r "$1"/. "$3/aligned/"  # too few GPS positions: measured unaligned (colmap_compare.py refits anyway)
  colmap model_converter --input_path "$3/aligned" --output_path "$3/txt" --output_type TXT >/dev/null 2>&1
}

stamp=$(date -u +%Y%m%d-%H%M%S)
report=$RESULTS/ground-vs-colmap-$stamp.md
{
  echo "# Ground tool against COLMAP 3.8 — $stamp, $(nproc) cores, threads $THREADS, $(git -C "$REPO" rev-parse --short HEAD)"
  echo
  echo "CPU: $(awk -F: '/model name/ {print $2; exit}' /proc/cpuinfo | sed 's/^ //'); COLMAP: feature_extractor"
  echo "(CPU SIFT, max_image_size 3200, 8192 features, one OPENCV camera) -> spatial_matcher (GPS, $NEIGHBORS neighbours)"
  echo "-> mapper. uavmosaic: uavmosaic-onboard (session) -> uavmosaic-ground --no-dense ${GROUND_ARGS:-}."
  echo "Both models aligned to the EXIF GPS positions by colmap model_aligner and measured by bench/colmap_compare.py."
} >"$report"

for f in $FLIGHTS; do
  IMG=$DATA/$f/images
  [[ -d $IMG ]] || { echo "no $IMG" >&2; continue; }
  W=$OUT/$f
  rm -rf "$W"
  mkdir -p "$W/colmap/sparse"
  echo "== $f: uavmosaic" >&2
  timed onboard "$ONBOARD" --source "replay:$IMG" --out "$W/session" --log-level warn --no-tiff
  # shellcheck disable=SC2086
  timed ground "$GROUND" "$W/session" --out "$W/ours" --threads "$THREADS" --no-dense ${GROUND_ARGS:-}
  gps_ref "$W/session" filename >"$W/gps_ref.txt"
  gps_ref "$W/session" stored_file >"$W/gps_ref_stored.txt"
  echo "== $f: COLMAP" >&2
  timed colmap_features colmap feature_extractor --database_path "$W/colmap/db.db" --image_path "$IMG" \
    --ImageReader.single_camera 1 --ImageReader.camera_model OPENCV --SiftExtraction.use_gpu 0 \
    --SiftExtraction.num_threads "$THREADS"
  timed colmap_matching colmap spatial_matcher --database_path "$W/colmap/db.db" --SiftMatching.use_gpu 0 \
    --SiftMatching.num_threads "$THREADS" --SpatialMatching.max_num_neighbors "$NEIGHBORS"
  timed colmap_mapper colmap mapper --database_path "$W/colmap/db.db" --image_path "$IMG" \
    --output_path "$W/colmap/sparse" --Mapper.num_threads "$THREADS"
  model=$(largest_model "$W/colmap/sparse")
  aligned_txt "$model" "$W/gps_ref.txt" "$W/colmap/eval"
  aligned_txt "$W/ours/sparse" "$W/gps_ref_stored.txt" "$W/ours/eval"
  "$PY" "$SCRIPT_DIR/colmap_compare.py" "$W/colmap/eval/txt" "$W/gps_ref.txt" >"$W/colmap.json"
  "$PY" "$SCRIPT_DIR/colmap_compare.py" "$W/ours/eval/txt" "$W/gps_ref.txt" --strip-prefix >"$W/ours.json"
  n_frames=$(find "$IMG" -maxdepth 1 -type f | wc -l)
  c_wall=$(sum_wall "$W"/colmap_*.time)
  o_wall=$(wall_s "$W/ground.time")
  ob_wall=$(wall_s "$W/onboard.time")
  "$PY" - "$W" "$f" "$n_frames" "$c_wall" "$o_wall" "$ob_wall" "$(max_peak "$W"/colmap_*.time)" \
    "$(peak_mib "$W/ground.time")" "$(peak_mib "$W/onboard.time")" \
    "$(sum_wall "$W/colmap_features.time")/$(sum_wall "$W/colmap_matching.time")/$(sum_wall "$W/colmap_mapper.time")" \
    >>"$report" <<'EOF'
import json, sys
w, flight, n, c_wall, o_wall, ob_wall, c_rss, o_rss, ob_rss, c_stages = sys.argv[1:]
c, o = json.load(open(w + "/colmap.json")), json.load(open(w + "/ours.json"))
s = json.load(open(w + "/ours/summary.json"))
t = s.get("timings", {})
def f(v, d=3):
    return "-" if v is None else (f"{v:.{d}f}" if isinstance(v, float) else str(v))
def cam(j):
    k = j["camera"]
    return f"f {k['f']:.1f}, c ({k['cx']:.1f}, {k['cy']:.1f}), k1 {k['k1']:.4f}, k2 {k['k2']:.4f}, p {k['p1']:.5f} {k['p2']:.5f}"
missing = sorted(set(c["names"]) - set(o["names"]))
print(f"\n## {flight} ({n} frames)\n")
print("| figure | COLMAP 3.8 | uavmosaic-ground | ours / COLMAP |")
print("|---|---|---|---|")
print(f"| images registered | {c['images']} | {o['images']} | {'every COLMAP image' if not missing else 'missing: ' + ' '.join(missing)} |")
print(f"| sparse points | {c['points']} | {o['points']} | {o['points'] / max(1, c['points']):.2f} |")
print(f"| observations | {c['observations']} | {o['observations']} | {o['observations'] / max(1, c['observations']):.2f} |")
print(f"| mean track length | {c['mean_track_length']:.2f} | {o['mean_track_length']:.2f} | |")
r = o['reprojection_rms_px'] / c['reprojection_rms_px']
print(f"| reprojection RMS (px, recomputed) | {f(c['reprojection_rms_px'])} | {f(o['reprojection_rms_px'])} | {r:.2f} |")
print(f"| reprojection mean (px) | {f(c['reprojection_mean_px'])} | {f(o['reprojection_mean_px'])} | |")
print(f"| camera | {cam(c)} | {cam(o)} | |")
def gps(j):
    return f"{f(j.get('gps_rms_m'), 2)} ({f(j.get('gps_rms_xy_m'), 2)} / {f(j.get('gps_rms_z_m'), 2)})"
print(f"| camera centres vs GPS, RMS after similarity, m: 3-D (horizontal / vertical) | {gps(c)} | {gps(o)} | |")
print(f"| wall s | {c_wall} (features/matching/mapper {c_stages}) | {o_wall} (+ onboard {ob_wall}) | {float(o_wall) / float(c_wall):.2f} ({(float(o_wall) + float(ob_wall)) / float(c_wall):.2f} with the onboard run) |")
print(f"| peak RSS MiB | {c_rss} | {o_rss} (onboard {ob_rss}) | |")
print(f"\nuavmosaic-ground stages (s): " + ", ".join(f"{k} {v:.1f}" for k, v in t.items() if isinstance(v, (int, float))))
EOF
done
cat "$report"
echo "kept: $report" >&2
