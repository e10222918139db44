# bench/lib.sh: measurement and formatting helpers shared by bench/run_real.sh and bench/run.sh (source it).
# Needs bash >= 5 (EPOCHREALTIME) and LC_ALL=C for "." decimals.

now_us() { echo "${EPOCHREALTIME//[.,]/}"; }

# read_status PID: sets S_STATE S_RSS S_HWM (kB); fails once /proc/PID is gone.
read_status() {
  S_STATE="" S_RSS=0 S_HWM=0
  local key val _rest
  {
    while read -r key val _rest; do
      case $key in
        State:) S_STATE=$val ;;
        VmRSS:) S_RSS=$val ;;
        VmHWM:) S_HWM=$val ;;
      esac
    done <"/proc/$1/status"
  } 2>/dev/null || return 1
}

# run_watched PREFIX CAP_KB TIMEOUT_S CMD...: runs CMD with stdout/stderr to PREFIX.{stdout,stderr}
# under the watchdog (CAP_KB / TIMEOUT_S of 0 = no cap). Sets W_RC, W_WALL_S, W_PEAK_KB,
# W_KILLED ("" | mem | timeout), W_KILL_RSS_KB. Never fails, so one tool cannot abort the table.
run_watched() {
  local prefix=$1 cap_kb=$2 timeout_s=$3
  shift 3
  local t0 t1 pid
  W_RC=0 W_PEAK_KB=0 W_KILLED="" W_KILL_RSS_KB=0
  t0=$(now_us)
  "$@" >"$prefix.stdout" 2>"$prefix.stderr" &
  pid=$!
  while read_status "$pid"; do
    # A zombie still answers kill -0 and has no Vm* lines: it has finished.
    [[ -z $S_STATE || $S_STATE == Z* ]] && break
    ((S_HWM > W_PEAK_KB)) && W_PEAK_KB=$S_HWM
    ((S_RSS > W_PEAK_KB)) && W_PEAK_KB=$S_RSS
    if ((cap_kb > 0 && S_RSS > cap_kb)); then
      kill -KILL "$pid" 2>/dev/null || true
      W_KILLED=mem W_KILL_RSS_KB=$S_RSS
      break
    fi
    if ((timeout_s > 0 && $(now_us) - t0 > timeout_s * 1000000)); then
      kill -KILL "$pid" 2>/dev/null || true
      W_KILLED=timeout
      break
    fi
    sleep 0.2
  done
  # Braces: silence bash's own "Killed" job notice; the table says what happened.
  { wait "$pid"; } 2>/dev/null || W_RC=$?
  t1=$(now_us)
  W_WALL_S=$(awk -v d=$((t1 - t0)) 'BEGIN { printf "%.2f", d / 1e6 }')
}

# peak_mib: the watchdog's peak in MiB; "—" when the process ended before a useful poll.
peak_mib() {
  if ((W_PEAK_KB >= 1024)); then fmt "$W_PEAK_KB" 0 1024; else echo "—"; fi
}

# fmt VALUE DECIMALS [DIVISOR]: number formatting, "—" for empty/non-numeric.
fmt() {
  local v=$1 dec=$2 div=${3:-1}
  if [[ $v =~ ^-?[0-9]+(\.[0-9]+)?([eE][-+]?[0-9]+)?$ ]]; then
    awk -v v="$v" -v d="$div" -v p="$dec" 'BEGIN { printf "%.*f", p, v / d }'
  else
    echo "—"
  fi
}

# cell TEXT: safe inside a markdown table cell (no pipes/newlines, bounded length).
cell() {
  local s=${1//$'\n'/ }
  s=${s//|/\\|}
  ((${#s} > 140)) && s="${s:0:137}..."
  echo "$s"
}

count_images() {  # -L: test data folders are often symlink farms
  [[ -d $1 ]] || { echo 0; return 0; }
  find -L "$1" -maxdepth 1 -type f \( -iname '*.jpg' -o -iname '*.jpeg' -o -iname '*.png' \) | wc -l
}

rc_text() {  # exit status -> "exit N" / "signal N"
  if (($1 > 128)); then echo "signal $(($1 - 128))"; else echo "exit $1"; fi
}

cpu_model() { awk -F': ' '/^model name/ { print $2; exit }' /proc/cpuinfo; }

# run_stitcher FDIR IMG_DIR TIMEOUT_S MEM_CAP_KB OURS_OK OURS_WALL_S: runs uavm-stitcher-bench under the watchdog and
# sets S_FRAMES S_REG S_WALL S_RSS S_STATUS S_RATIO (S_FRAMES keeps its value when the tool prints no JSON). The ratio
# only means something against a successful run of ours; a killed or timed-out stitcher ran at least that long, so
# it is a lower bound.
run_stitcher() {
  local fdir=$1 img_dir=$2 timeout_s=$3 mem_cap_kb=$4 ours_ok=$5 ours_wall_s=$6 json j_frames j_reg r
  S_REG="—" S_WALL="" S_RSS="—" S_STATUS="" S_RATIO="—"
  rm -f "$fdir/stitcher.png"
  run_watched "$fdir/stitcher" "$mem_cap_kb" "$timeout_s" "$STITCHER_BIN" --images "$img_dir" --out "$fdir/stitcher.png"
  S_RSS=$(peak_mib)
  json=$(grep '^{' "$fdir/stitcher.stdout" | tail -n 1 || true)
  if [[ -n $json ]] && IFS=$'\x1f' read -r S_STATUS j_frames j_reg < <(
    jq -r '[.status, .frames, .frames_in_result] | map(tostring) | join("\u001f")' <<<"$json" 2>/dev/null); then
    S_FRAMES=$j_frames S_REG=$j_reg
  fi
  if [[ $W_KILLED == mem ]]; then
    S_WALL="killed at $(fmt "$W_KILL_RSS_KB" 1 1048576) GB (after $W_WALL_S s)"
  elif [[ $W_KILLED == timeout ]]; then
    S_WALL="timeout at $timeout_s s"
  elif [[ $S_STATUS == ok ]]; then
    S_WALL=$W_WALL_S
  elif [[ -n $S_STATUS ]]; then
    S_WALL="failed: ${S_STATUS#failed: }"
  else
    S_WALL="failed: $(rc_text "$W_RC"), no JSON"
  fi
  if ((ours_ok)); then
    r=$(awk -v a="$W_WALL_S" -v b="$ours_wall_s" 'BEGIN { if (b > 0) printf "%.2f", a / b }')
    if [[ -n $r ]]; then
      if [[ $S_STATUS == ok ]]; then S_RATIO="${r}x"
      elif [[ -n $W_KILLED ]]; then S_RATIO="≥ ${r}x"
      fi
    fi
  fi
}

# run_phased PREFIX CMD...: runs CMD (stdout/stderr to PREFIX.{stdout,stderr}) and samples it from outside every
# SAMPLE_S seconds (default 0.05; a phase shorter than that is seen once or not at all): VmRSS and RssAnon from
# /proc/PID/status, and the phase the program is in from the name of its memory watch's thread ("mem:<phase>" in
# /proc/PID/task/*/comm, see core/util/memory_watch.h). Writes PREFIX.phases.tsv (phase, peak VmRSS kB, peak RssAnon
# kB, samples, first and last sample's second) in the order the phases ran.
# Sets W_RC, W_WALL_S, W_PEAK_KB (largest VmRSS or VmHWM sampled), W_PEAK_ANON_KB.
run_phased() {
  local prefix=$1
  shift
  local t0 pid key val _rest rss anon hwm state phase comm f now
  declare -A P_RSS=() P_ANON=() P_N=() P_FIRST=() P_LAST=()
  local order=()
  W_RC=0 W_PEAK_KB=0 W_PEAK_ANON_KB=0
  t0=$(now_us)
  "$@" >"$prefix.stdout" 2>"$prefix.stderr" &
  pid=$!
  phase=start
  while :; do
    rss=0 anon=0 hwm=0 state=""
    {
      while read -r key val _rest; do
        case $key in
          State:) state=$val ;;
          VmRSS:) rss=$val ;;
          RssAnon:) anon=$val ;;
          VmHWM:) hwm=$val ;;
        esac
      done <"/proc/$pid/status"
    } 2>/dev/null || break
    [[ -z $state || $state == Z* ]] && break
    for f in /proc/"$pid"/task/*/comm; do
      read -r comm <"$f" 2>/dev/null || continue
      if [[ $comm == mem:* ]]; then phase=${comm#mem:}; break; fi
    done
    now=$(($(now_us) - t0))
    if [[ -z ${P_N[$phase]:-} ]]; then
      order+=("$phase") P_RSS[$phase]=0 P_ANON[$phase]=0 P_N[$phase]=0 P_FIRST[$phase]=$now
    fi
    ((rss > P_RSS[$phase])) && P_RSS[$phase]=$rss
    ((anon > P_ANON[$phase])) && P_ANON[$phase]=$anon
    P_N[$phase]=$((P_N[$phase] + 1)) P_LAST[$phase]=$now
    ((rss > W_PEAK_KB)) && W_PEAK_KB=$rss
    ((hwm > W_PEAK_KB)) && W_PEAK_KB=$hwm
    ((anon > W_PEAK_ANON_KB)) && W_PEAK_ANON_KB=$anon
    sleep "${SAMPLE_S:-0.05}"
  done
  { wait "$pid"; } 2>/dev/null || W_RC=$?
  W_WALL_S=$(awk -v d=$(($(now_us) - t0)) 'BEGIN { printf "%.2f", d / 1e6 }')
  : >"$prefix.phases.tsv"
  for phase in "${order[@]}"; do
    printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$phase" "${P_RSS[$phase]}" "${P_ANON[$phase]}" "${P_N[$phase]}" \
      "$(awk -v t="${P_FIRST[$phase]}" 'BEGIN { printf "%.2f", t / 1e6 }')" \
      "$(awk -v t="${P_LAST[$phase]}" 'BEGIN { printf "%.2f", t / 1e6 }')" >>"$prefix.phases.tsv"
  done
}
