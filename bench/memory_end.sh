#!/usr/bin/env bash
# memory_end.sh MEMORY_RUN_DIR [FRAMES...]
#
# The end of the flight's memory in minutes instead of the hour a 5000-frame flight takes: each simulated flight that
# bench/memory.sh recorded (MEMORY_RUN_DIR/sim_FRAMES, with MEMORY_RUN_DIR/sim_memory.yaml) is copied and resumed
# (--resume: every frame registered again from the session, no feature detection) and its phases are sampled from
# outside as bench/memory.sh does (bench/lib.sh run_phased: VmRSS and RssAnon every 50 ms, attributed by the memory
# watch's thread name). The resumed flight phase has no detector, so only the end phases' figures stand for a real
# run's (resumed and whole runs agreed within 9 MiB on every end phase at 5000 frames, 2026-11-27). Each phase's
# peak against the same phase of the first FRAMES given (default: every sim_* in MEMORY_RUN_DIR, smallest first).
#
# Environment: REPEAT (runs of each flight, default 1; each phase's figure is the median of its runs), BUDGET_MIB
# (default 256), SAMPLE_S (seconds between samples, default 0.05: 0.02 sees the 200-frame flight's 28 ms `adjust`),
# EXTRA_ARGS (e.g. "--config exp.yaml"), UAVM_BUILD_DIR, TMPDIR (the copies), REPORTS_DIR (keeps each run's
# report.json and log there as sim_FRAMES[.RUN].report.json / .log).
set -euo pipefail
export LC_ALL=C

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $1 == -h || $1 == --help ]]; then
  sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"

RUN_DIR=$(cd "$1" && pwd)
shift
PLAN=$RUN_DIR/sim_memory.yaml
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS_BIN=$BUILD/firmware_app/uavmosaic-onboard
BUDGET_MIB=${BUDGET_MIB:-256}
log() { echo "[memory_end] $*" >&2; }
[[ -f $PLAN ]] || { log "$PLAN missing: MEMORY_RUN_DIR is an OUT_DIR of bench/memory.sh"; exit 1; }
[[ -x $OURS_BIN ]] || { log "$OURS_BIN missing (scripts/build.sh)"; exit 1; }
REPEAT=${REPEAT:-1}
median() { printf '%s\n' "$@" | sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
FRAMES=("$@")
if [[ ${#FRAMES[@]} -eq 0 ]]; then
  mapfile -t FRAMES < <(find "$RUN_DIR" -maxdepth 1 -type d -name 'sim_*' -printf '%f\n' | sed 's/^sim_//' | sort -n)
fi
[[ ${#FRAMES[@]} -gt 0 ]] || { log "no sim_* session in $RUN_DIR"; exit 1; }
WORK=$(mktemp -d "${TMPDIR:-/tmp}/uavm-memory-end.XXXXXX")
trap 'rm -rf "$WORK"' EXIT

declare -A PEAK ANON
PHASES=()
for n in "${FRAMES[@]}"; do
  [[ -f $RUN_DIR/sim_$n/journal.jsonl ]] || { log "sim_$n: no session"; exit 1; }
  for ((rep = 1; rep <= REPEAT; rep++)); do
    rm -rf "$WORK/s"
    cp -a "$RUN_DIR/sim_$n" "$WORK/s"
    log "sim_$n: resumed ($rep/$REPEAT)"
    # shellcheck disable=SC2086 # EXTRA_ARGS is a list of words
    run_phased "$WORK/r" "$OURS_BIN" --source "sim:$PLAN" --max-frames "$n" --no-tiff --out "$WORK/s" \
      --memory-budget "$BUDGET_MIB" --resume ${EXTRA_ARGS:-}
    ((W_RC == 0)) || { log "sim_$n: exit $W_RC"; tail -n 5 "$WORK/r.stdout" >&2; exit 1; }
    if [[ -n ${REPORTS_DIR:-} ]]; then
      mkdir -p "$REPORTS_DIR"
      suffix=""
      ((REPEAT == 1)) || suffix=".$rep"
      cp "$WORK/s/report.json" "$REPORTS_DIR/sim_$n$suffix.report.json"
      cat "$WORK/r.stdout" "$WORK/r.stderr" >"$REPORTS_DIR/sim_$n$suffix.log"
    fi
    while IFS=$'\t' read -r phase rss anon _n _first _last; do
      [[ " ${PHASES[*]} " == *" $phase "* ]] || PHASES+=("$phase")
      PEAK[$phase.$n]+="$rss " ANON[$phase.$n]+="$anon "
    done <"$WORK/r.phases.tsv"
  done
  # The median of the repeats (the lower middle of an even count): one resumed run's end phases vary by a few MiB.
  for key in "${!PEAK[@]}"; do
    [[ $key == *".$n" ]] || continue
    # shellcheck disable=SC2086 # the runs' figures, a word each
    PEAK[$key]=$(median ${PEAK[$key]}) ANON[$key]=$(median ${ANON[$key]})
  done
done

header="| phase |"
rule="|---|"
for n in "${FRAMES[@]}"; do header+=" $n frames: VmRSS / RssAnon MiB |" rule+="---|"; done
for n in "${FRAMES[@]:1}"; do header+=" $n / ${FRAMES[0]} |" rule+="---|"; done
echo "$header"
echo "$rule"
for phase in "${PHASES[@]}"; do
  row="| $phase |"
  for n in "${FRAMES[@]}"; do
    if [[ -n ${PEAK[$phase.$n]:-} ]]; then
      row+=" $(fmt "${PEAK[$phase.$n]}" 1 1024) / $(fmt "${ANON[$phase.$n]}" 1 1024) |"
    else
      row+=" — (too short to sample) |"
    fi
  done
  ref=${PEAK[$phase.${FRAMES[0]}]:-0} ref_anon=${ANON[$phase.${FRAMES[0]}]:-0}
  for n in "${FRAMES[@]:1}"; do
    if ((ref > 0 && ref_anon > 0 && ${PEAK[$phase.$n]:-0} > 0)); then
      row+=" $(awk -v a="${PEAK[$phase.$n]}" -v b="$ref" -v c="${ANON[$phase.$n]}" -v d="$ref_anon" \
        'BEGIN { printf "%.2f / %.2f", a / b, c / d }') |"
    else
      row+=" — |"
    fi
  done
  echo "$row"
done
