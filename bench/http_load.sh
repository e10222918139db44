#!/usr/bin/env bash
# bench/http_load.sh BUILD_DIR DATA_DIR [REPEATS] [CLIENTS] [PACE_MS]: the live HTTP server's effect on the frame loop.
# The same replay of DATA_DIR (e.g. ../shared/data/brighton_beach/images beside the project) runs without --http and with --http while
# CLIENTS client threads (Python, persistent connections) on loopback fetch /live.jpg and /status.json back to back (bounded: at most 5000 requests per
# loop; PACE_MS > 0 sleeps that long between a loop's requests, as a live page polling would). Runs alternate (off, on, off, on, ...) so that load from other processes hits both alike. Prints the median
# per-frame frame_total (ms, report.json stages_ms) of each run, the medians over runs and the ratio, and saves the
# table to bench/results/http-load-<date>-vm.md.
set -euo pipefail
export LC_ALL=C
build=${1:?build dir}
data=${2:?image folder}
repeats=${3:-3}
clients=${4:-4}
pace_ms=${5:-0}
bin=$build/firmware_app/uavmosaic-onboard
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d "${TMPDIR:-/tmp}/uavm_http_load.XXXXXX")
trap 'rm -rf "$work"' EXIT
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')

# The clients: one Python process, CLIENTS threads on persistent connections (no process per request, so that the
# client's own CPU stays small), each fetching until the server goes away or 5000 requests.
client_py='
import http.client, sys, threading, time
port, n_clients, pace, out = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]) / 1000, sys.argv[4]
counts = [[0, 0] for _ in range(n_clients)]
def loop(k):
    conn, ok_once = None, False
    for i in range(5000):
        try:
            if conn is None: conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
            conn.request("GET", "/live.jpg" if i % 2 == 0 else "/status.json")
            r = conn.getresponse(); r.read()
            counts[k][0] += 1
            if r.status == 200: counts[k][1] += 1; ok_once = True
            if r.getheader("Connection", "").lower() == "close": conn.close(); conn = None
        except Exception:
            if conn: conn.close()
            conn = None
            if ok_once: break  # the run is over
            time.sleep(0.2); continue
        if pace > 0: time.sleep(pace)
threads = [threading.Thread(target=loop, args=(k,)) for k in range(n_clients)]
[t.start() for t in threads]; [t.join() for t in threads]
open(out, "w").write("%d %d\n" % (sum(c[0] for c in counts), sum(c[1] for c in counts)))
'

median_ms() { python3 -c 'import json,sys; print("%.1f" % json.load(open(sys.argv[1]))["stages_ms"]["frame_total"]["median"])' "$1"; }

rows=()
offs=()
ons=()
total_req=0
total_ok=0
for r in $(seq 1 "$repeats"); do
  for mode in off on; do
    out=$work/$mode$r
    if [ $mode = off ]; then
      "$bin" --source "replay:$data" --out "$out" --no-products --log-level warn
    else
      "$bin" --source "replay:$data" --out "$out" --no-products --log-level warn --http "127.0.0.1:$port" &
      pid=$!
      /usr/bin/python3 -c "$client_py" "$port" "$clients" "$pace_ms" "$work/clients" &
      cpid=$!
      # CPU of the server's threads (named uavm-http*) and of the whole process, sampled until it exits: what the
      # live view itself costs, independent of other load on the machine.
      http_ticks=0 proc_ticks=0
      while kill -0 $pid 2>/dev/null; do
        t=0
        for task in /proc/$pid/task/*; do
          comm=""
          read -r comm <"$task/comm" 2>/dev/null || true
          if [[ $comm == uavm-http* ]]; then
            read -r -a f <"$task/stat" 2>/dev/null || continue
            t=$((t + f[13] + f[14]))
          fi
        done
        read -r -a f </proc/$pid/stat 2>/dev/null || break
        [ $t -gt 0 ] && http_ticks=$t
        proc_ticks=$((f[13] + f[14]))
        sleep 0.5
      done
      wait $pid
      wait $cpid
      read -r n ok <"$work/clients"
      total_req=$((total_req + n))
      total_ok=$((total_ok + ok))
    fi
    m=$(median_ms "$out/report.json")
    cpu=""
    if [ $mode = on ]; then
      cpu="$(awk -v h=$http_ticks -v p=$proc_ticks 'BEGIN {printf "%.2f s of %.1f s (%.1f %%)", h/100, p/100, 100*h/p}')"
    fi
    echo "run $r $mode: median frame_total $m ms $cpu"
    rows+=("| $r | $mode | $m | $cpu |")
    if [ $mode = off ]; then offs+=("$m"); else ons+=("$m"); fi
    rm -rf "$out"
  done
done
med() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print (NR%2 ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2)}'; }
moff=$(med "${offs[@]}")
mon=$(med "${ons[@]}")
ratio=$(awk -v a="$mon" -v b="$moff" 'BEGIN {printf "%.3f", a/b}')
stamp=$(date -u +%Y%m%d-%H%M%S)
mkdir -p "$here/results"
res=$here/results/http-load-$stamp-vm.md
{
  echo "# Live HTTP server under load: per-frame time ($stamp UTC)"
  echo
  echo "Data: \`$data\` ($(ls "$data" | wc -l) frames), $repeats runs each, alternating; with --http: $clients client threads on"
  echo "loopback fetching /live.jpg and /status.json, pause between requests $pace_ms ms ($total_req requests, $total_ok answered 200)."
  echo "The client (one Python process, persistent connections) runs on the same cores as the frame loop."
  echo "Machine: $(nproc) cores, $(uname -r), shared with other sessions; load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)."
  echo
  echo "| run | --http | median frame_total ms | CPU of the server threads / whole process (sampled every 0.5 s) |"
  echo "|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
  echo
  echo "| | median over runs, ms |"
  echo "|---|---|"
  echo "| without --http | $moff |"
  echo "| with --http + clients | $mon |"
  echo "| ratio | $ratio |"
} | tee "$res"
echo "saved $res"
