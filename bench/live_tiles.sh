#!/usr/bin/env bash
# bench/live_tiles.sh BUILD_DIR DATA_DIR [REPEATS] [PACE_MS]: what the live tile pyramid costs the flight and how soon
# a frame reaches the ground station. The same replay of DATA_DIR (e.g. ../shared/data/caliterra/images beside the
# project) runs with --http and --no-live-tiles, then with --http and live tiles, alternating (off, on, off, on, ...)
# so that load from other processes hits both alike; with tiles a client (one Python process) polls /status.json and
# fetches the newest tiles at the finest zoom, as the live page does. PACE_MS > 0 makes the frame loop take at least
# that long per frame (--process-delay-ms: a camera triggering every PACE_MS), 0 replays as fast as the CPU allows.
# Prints, per run, the median per-frame frame_total (report.json stages_ms), wall time, peak RSS against the budget,
# and with tiles the worker's time, the tiles written and the tile latency (frame registered -> its tiles published,
# median and p95, report.json live_tiles); then the medians over runs and the on/off ratios. Saves the table to
# bench/results/live-tiles-<date>.md.
set -euo pipefail
export LC_ALL=C
build=${1:?build dir}
data=${2:?image folder}
repeats=${3:-3}
pace_ms=${4:-0}
bin=$build/firmware_app/uavmosaic-onboard
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d "${TMPDIR:-/tmp}/uavm_live_tiles.XXXXXX")
trap 'rm -rf "$work"' EXIT
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')

# The client: every second /status.json, then the finest-zoom tiles under the newest tile set's bounds (at most 16),
# revalidated with their ETags as a browser would. Counts answers by status.
client_py='
import http.client, json, math, sys, time
port, out = int(sys.argv[1]), sys.argv[2]
def tile_xy(lon, lat, z):
    n = 2 ** z
    x = int((lon + 180) / 360 * n)
    y = int((1 - math.log(math.tan(math.radians(lat)) + 1 / math.cos(math.radians(lat))) / math.pi) / 2 * n)
    return x, y
counts, etags, seen = {}, {}, False
conn = None
while True:
    try:
        if conn is None: conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        conn.request("GET", "/status.json"); r = conn.getresponse(); st = json.loads(r.read()); seen = True
        t = st.get("tiles")
        if t and t.get("geographic"):
            z = t["max_zoom"]; w, s, e, n = t["bounds"]
            x0, y0 = tile_xy(w, n, z); x1, y1 = tile_xy(e, s, z)
            tiles = [(x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)][-16:]
            for x, y in tiles:
                path = "/tiles/%d/%d/%d.png" % (z, x, y)
                h = {"If-None-Match": etags[path]} if path in etags else {}
                conn.request("GET", path, headers=h); r = conn.getresponse(); r.read()
                counts[r.status] = counts.get(r.status, 0) + 1
                if r.getheader("ETag"): etags[path] = r.getheader("ETag")
                if r.getheader("Connection", "").lower() == "close": conn.close(); conn = None; break
        if st.get("state") in ("done", "failed"): break
    except Exception:
        if conn: conn.close()
        conn = None
        if seen: break
    time.sleep(1.0)
open(out, "w").write(" ".join("%s:%d" % kv for kv in sorted(counts.items())) + "\n")
'

field() { python3 -c 'import json,sys
r = json.load(open(sys.argv[1])); keys = sys.argv[2].split(".")
for k in keys: r = r[k]
print(("%.1f" % r) if isinstance(r, float) else r)' "$1" "$2"; }

rows=()
declare -A frame wall
for mode in off on; do frame[$mode]=""; wall[$mode]=""; done
lat_med=() lat_p95=()
for r in $(seq 1 "$repeats"); do
  for mode in off on; do
    out=$work/$mode$r
    extra=(--no-live-tiles)
    [ $mode = on ] && extra=()
    "$bin" --source "replay:$data" --out "$out" --log-level warn --http "127.0.0.1:$port" \
      --process-delay-ms "$pace_ms" "${extra[@]}" &
    pid=$!
    clients=""
    if [ $mode = on ]; then
      /usr/bin/python3 -c "$client_py" "$port" "$work/client" &
      cpid=$!
    fi
    wait $pid
    if [ $mode = on ]; then
      wait $cpid || true
      clients=$(cat "$work/client")
    fi
    rep=$out/report.json
    m=$(field "$rep" stages_ms.frame_total.median)
    w=$(field "$rep" wall_s)
    rss=$(field "$rep" peak_rss_mib)
    budget=$(field "$rep" memory.budget_mib 2>/dev/null || echo "?")
    frame[$mode]+="$m "
    wall[$mode]+="$w "
    tiles="| | | | |"
    if [ $mode = on ]; then
      lm=$(field "$rep" live_tiles.latency_ms_median)
      lp=$(field "$rep" live_tiles.latency_ms_p95)
      lat_med+=("$lm")
      lat_p95+=("$lp")
      tiles="| $(field "$rep" live_tiles.worker_ms) | $(field "$rep" live_tiles.tiles_written) | $lm / $lp | $clients |"
    fi
    echo "run $r $mode: frame_total median $m ms, wall $w s, peak RSS $rss / $budget MiB $tiles"
    rows+=("| $r | $mode | $m | $w | $rss / $budget $tiles")
    rm -rf "$out"
  done
done
med() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print (NR%2 ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2)}'; }
# shellcheck disable=SC2086
foff=$(med ${frame[off]}) fon=$(med ${frame[on]}) woff=$(med ${wall[off]}) won=$(med ${wall[on]})
ratio() { awk -v a="$1" -v b="$2" 'BEGIN {printf "%.3f", a/b}'; }
stamp=$(date -u +%Y%m%d-%H%M%S)
mkdir -p "$here/results"
res=$here/results/live-tiles-$stamp.md
{
  echo "# Live tiles: cost to the flight and tile latency ($stamp UTC)"
  echo
  echo "Data: \`$data\` ($(ls "$data" | wc -l) files), $repeats runs each, alternating; all runs with --http; frame loop"
  echo "paced at ${pace_ms} ms per frame (0 = as fast as the CPU allows). Default settings (1000 px working copy,"
  echo "products on). Machine: $(nproc) cores, $(uname -r), shared; load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)."
  echo
  echo "| run | live tiles | median frame_total ms | wall s | peak RSS / budget MiB | worker ms (wall, niced) | tiles written | latency median / p95 ms | client answers |"
  echo "|---|---|---|---|---|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
  echo
  echo "| | off | on | on/off |"
  echo "|---|---|---|---|"
  echo "| median frame_total ms | $foff | $fon | $(ratio "$fon" "$foff") |"
  echo "| median wall s | $woff | $won | $(ratio "$won" "$woff") |"
  echo "| tile latency median / p95 ms (median over runs) | | $(med "${lat_med[@]}") / $(med "${lat_p95[@]}") | |"
} | tee "$res"
echo "saved $res"
