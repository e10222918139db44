#!/usr/bin/env bash
# cgroup_run.sh LIMIT_MIB COMMAND [ARGS...]
#
# Runs COMMAND inside a fresh memory cgroup whose hard limit is LIMIT_MIB (v1 "memory" hierarchy, or v2 with the memory
# controller), as the drone's systemd unit does with MemoryMax, and says how it ended: its exit status, whether the
# kernel OOM-killed anything in the group, and the group's peak (which also counts the page cache of the files the
# command reads and writes; the kernel reclaims that before it kills). Needs root. Exits with COMMAND's status, 137 on
# an OOM kill. tests/memory_limit_test does the same for short flights; this is for the long ones (bench/).
set -euo pipefail
if [[ $# -lt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,8p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
[[ $1 =~ ^[0-9]+$ ]] || { echo "[cgroup_run] LIMIT_MIB must be a number of MiB" >&2; exit 2; }
LIMIT_MIB=$((10#$1))  # base 10: "010" is ten, not octal eight
shift
((LIMIT_MIB >= 1)) || { echo "[cgroup_run] LIMIT_MIB must be at least 1" >&2; exit 2; }
NAME=uavm-bench-$$
DIR=
# Kills whatever is left in the group (a background child, or the command after the script was signalled), then
# removes it; says so when it cannot.
# shellcheck disable=SC2317 # run by the EXIT trap
cleanup() {
  [[ -n $DIR && -d $DIR ]] || return 0
  local pid
  for _ in 1 2 3 4 5 6 7 8 9 10; do
    [[ -s $DIR/cgroup.procs ]] || break
    while read -r pid; do kill -9 "$pid" 2>/dev/null || true; done <"$DIR/cgroup.procs"
    sleep 0.2
  done
  rmdir "$DIR" 2>/dev/null || echo "[cgroup_run] could not remove $DIR (still busy)" >&2
}
trap cleanup EXIT
if [[ -d /sys/fs/cgroup/memory ]]; then
  DIR=/sys/fs/cgroup/memory/$NAME
  mkdir "$DIR"
  echo $((LIMIT_MIB << 20)) >"$DIR/memory.limit_in_bytes"
  # With swap accounting, the same limit on memory + swap: a hard limit, not a push to swap (as v2's swap.max 0).
  [[ ! -f $DIR/memory.memsw.limit_in_bytes ]] || echo $((LIMIT_MIB << 20)) >"$DIR/memory.memsw.limit_in_bytes"
  PEAK_FILE=memory.max_usage_in_bytes
elif grep -qw memory /sys/fs/cgroup/cgroup.controllers 2>/dev/null; then
  DIR=/sys/fs/cgroup/$NAME
  mkdir "$DIR"
  if [[ ! -f $DIR/memory.max ]]; then
    echo "[cgroup_run] the memory controller is not enabled for child groups (cgroup.subtree_control)" >&2
    exit 2
  fi
  echo $((LIMIT_MIB << 20)) >"$DIR/memory.max"
  echo 0 >"$DIR/memory.swap.max" 2>/dev/null || true
  PEAK_FILE=memory.peak  # Linux 5.19 and later
else
  echo "[cgroup_run] no memory cgroup hierarchy (neither v1 memory nor v2 with the memory controller)" >&2
  exit 2
fi

set +e
bash -c 'echo $$ >"$1/cgroup.procs" && shift && exec "$@"' cgroup-run "$DIR" "$@"
rc=$?
set -e
ooms=0
if [[ -f $DIR/memory.oom_control ]]; then
  ooms=$(awk '$1 == "oom_kill" {print $2}' "$DIR/memory.oom_control")
elif [[ -f $DIR/memory.events ]]; then
  ooms=$(awk '$1 == "oom_kill" {print $2}' "$DIR/memory.events")
fi
peak="n/a"
[[ ! -f $DIR/$PEAK_FILE ]] || peak="$(($(cat "$DIR/$PEAK_FILE") >> 20)) MiB"
echo "[cgroup_run] limit ${LIMIT_MIB} MiB: exit $rc, OOM kills ${ooms:-0} (any makes the exit 137), group peak $peak" >&2
((${ooms:-0} == 0)) || exit 137
exit "$rc"
