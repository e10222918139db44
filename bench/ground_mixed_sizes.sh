#!/usr/bin/env bash
# ground_mixed_sizes.sh DATA_DIR [OUT_DIR]
#
# The ground tool on a flight of two image sizes: uavmosaic-onboard on DATA_DIR/brighton_beach/images into a session,
# the session copied with its first registered frame cropped to its centre 0.9x (gdal_translate, frames.csv's size
# changed to match), then uavmosaic-ground --render-previews on both (and --no-dense on the original). Prints each
# run's closing line; summary.json, the previews and the logs stay in OUT_DIR (plain_dense/, mixed_out/, plain/).
#
# Environment: UAVM_BUILD_DIR (default <repo>/build), THREADS (default 2).
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
DATA=$1
OUT=${2:-$(mktemp -d /tmp/ground_mixed.XXXXXX)}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
THREADS=${THREADS:-2}
for b in "$BUILD/firmware_app/uavmosaic-onboard" "$BUILD/ground_app/uavmosaic-ground"; do
  [[ -x $b ]] || { echo "missing $b (scripts/build.sh)" >&2; exit 2; }
done
command -v gdal_translate >/dev/null || { echo "gdal_translate missing (gdal-bin)" >&2; exit 2; }
[[ -d $DATA/brighton_beach/images ]] || { echo "no $DATA/brighton_beach/images" >&2; exit 2; }
mkdir -p "$OUT"
"$BUILD/firmware_app/uavmosaic-onboard" --source "replay:$DATA/brighton_beach/images" --out "$OUT/session" \
  --log-level warn --no-tiff >"$OUT/onboard.log" 2>&1
rm -rf "$OUT/mixed"
cp -a "$OUT/session" "$OUT/mixed"
python3 - "$OUT" <<'PY'
import csv, os, subprocess, sys
out = sys.argv[1]
rows = list(csv.reader(open(f"{out}/session/frames.csv")))
h = rows[0]
for r in rows[1:]:
    if r[h.index("registered")] != "1":
        continue
    path = f"{out}/mixed/frames/" + r[h.index("stored_file")]
    width, height = int(r[h.index("width")]), int(r[h.index("height")])
    w, hh = width * 9 // 10, height * 9 // 10
    subprocess.run(["gdal_translate", "-q", "-of", "JPEG", "-co", "QUALITY=95", "-srcwin", str((width - w) // 2),
                    str((height - hh) // 2), str(w), str(hh), path, path + ".crop.jpg"], check=True)
    os.replace(path + ".crop.jpg", path)
    r[h.index("width")], r[h.index("height")] = str(w), str(hh)
    print(f"frame {r[0]} cropped to {w}x{hh}")
    break
csv.writer(open(f"{out}/mixed/frames.csv", "w", newline=""), lineterminator="\n").writerows(rows)
PY
run() {  # NAME SESSION ARGS...
  local name=$1 session=$2
  shift 2
  /usr/bin/time -v "$BUILD/ground_app/uavmosaic-ground" "$session" --out "$OUT/$name" --threads "$THREADS" "$@" \
    >"$OUT/$name.log" 2>"$OUT/$name.err"
  grep 'uavmosaic-ground: [0-9]* frames' "$OUT/$name.err" | sed "s/^/$name: /"
}
run plain "$OUT/session" --no-dense
run mixed_out "$OUT/mixed" --render-previews
run plain_dense "$OUT/session" --render-previews
