#!/usr/bin/env bash
# bench/http_load.sh BUILD_DIR DATA_DIR [REPEATS] [CLIENTS]: the live HTTP server's effect on the frame loop.
# The same replay of DATA_DIR (e.g. /work/shared/data/brighton_beach/images) runs without --http and with --http while
# CLIENTS curl loops on loopback fetch /live.jpg and /status.json back to back (bounded: at most 5000 requests per
# loop). Runs alternate (off, on, off, on, ...) so that load from other processes hits both alike. Prints the median
# per-frame frame_total (ms, report.json stages_ms) of each run, the medians over runs and the ratio, and saves the
# table to bench/results/http-load-<date>-vm.md.
set -euo pipefail
export LC_ALL=C
build=${1:?build dir}
data=${2:?image folder}
repeats=${3:-3}
clients=${4:-4}
bin=$build/firmware_app/uavmosaic-onboard
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d /tmp/uavm_http_load.XXXXXX)
trap 'rm -rf "$work"' EXIT
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')

client_loop() {  # client_loop ID: fetches until the server goes away or 5000 requests
  local n=0 ok=0
  sleep 1
  while [ $n -lt 5000 ]; do
    if [ $((n % 2)) -eq 0 ]; then path=/live.jpg; else path=/status.json; fi
    code=$(curl -s -o /dev/null -w '%{http_code}' --max-time 5 "http://127.0.0.1:$port$path" || true)
    n=$((n + 1))
    [ "$code" = 200 ] && ok=$((ok + 1))
    if [ "$code" = 000 ] && [ $ok -gt 0 ]; then break; fi  # the run is over
  done
  echo "$n $ok" >"$work/client.$1"
}

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
      cpids=()
      for c in $(seq 1 "$clients"); do client_loop "$c" & cpids+=($!); done
      wait $pid
      for p in "${cpids[@]}"; do wait "$p"; done
      for c in $(seq 1 "$clients"); do
        read -r n ok <"$work/client.$c"
        total_req=$((total_req + n))
        total_ok=$((total_ok + ok))
      done
    fi
    m=$(median_ms "$out/report.json")
    echo "run $r $mode: median frame_total $m ms"
    rows+=("| $r | $mode | $m |")
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
  echo "Data: \`$data\` ($(ls "$data" | wc -l) frames), $repeats runs each, alternating; with --http: $clients curl loops on"
  echo "loopback fetching /live.jpg and /status.json back to back ($total_req requests, $total_ok answered 200)."
  echo "Machine: $(nproc) cores, $(uname -r), shared with other sessions (noise of a few % between runs)."
  echo
  echo "| run | --http | median frame_total ms |"
  echo "|---|---|---|"
  printf '%s\n' "${rows[@]}"
  echo
  echo "| | median over runs, ms |"
  echo "|---|---|"
  echo "| without --http | $moff |"
  echo "| with --http + clients | $mon |"
  echo "| ratio | $ratio |"
} | tee "$res"
echo "saved $res"
