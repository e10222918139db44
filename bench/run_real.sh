#!/usr/bin/env bash
# run_real.sh DATA_DIR [OUT_DIR]
#
# Compares uavmosaic-onboard with OpenCV's cv::Stitcher (uavm-stitcher-bench) on the real
# full-resolution flights DATA_DIR/{brighton_beach,caliterra}/images and prints one markdown
# table (also saved to OUT_DIR/table.md and $RESULTS_DIR/<date>-<hostname>.md).
#
# Environment:
#   UAVM_BUILD_DIR     build tree (default <repo>/build)
#   STITCHER_TIMEOUT_S wall-time cap for cv::Stitcher, s (default 600)
#   STITCHER_MEM_GB    RSS cap for cv::Stitcher, GiB, may be fractional (default 12)
#   OURS_TIMEOUT_S     wall-time cap for uavmosaic-onboard, s (default 0 = none)
#   OURS_ARGS          extra uavmosaic-onboard options, e.g. "--model affine"
#   FLIGHTS            space-separated flight folders (default "brighton_beach caliterra")
#   UAVM_RESULTS_DIR   where the dated copy of the table goes (default bench/results)
#
# Wall time is measured here, outside both processes (load + work + write), so the two tools
# are timed the same way. Peak RSS is the largest VmHWM/VmRSS seen in /proc/PID/status,
# polled every 0.2 s (VmHWM is the kernel's own high-water mark, so short spikes between
# polls are still counted; only growth in the last <0.2 s before exit could be missed).
set -euo pipefail
export LC_ALL=C  # "." as decimal point for printf/awk

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")

if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,20p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi

DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
OUT_DIR=${2:-$RESULTS_DIR/real-$STAMP}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS_BIN=$BUILD/firmware_app/uavmosaic-onboard
read -r -a OURS_EXTRA <<<"${OURS_ARGS:-}"
STITCHER_BIN=$BUILD/bench/uavm-stitcher-bench
STITCHER_TIMEOUT_S=${STITCHER_TIMEOUT_S:-600}
STITCHER_MEM_GB=${STITCHER_MEM_GB:-12}
OURS_TIMEOUT_S=${OURS_TIMEOUT_S:-0}
FLIGHTS=${FLIGHTS:-brighton_beach caliterra}

log() { echo "[run_real] $*" >&2; }

if ! command -v jq >/dev/null 2>&1; then
  log "jq missing, installing it"
  if ! { apt-get update -qq && apt-get install -y -qq jq; } >&2; then
    log "cannot install jq"
    exit 1
  fi
fi

mkdir -p "$OUT_DIR" "$RESULTS_DIR"
OUT_DIR=$(cd "$OUT_DIR" && pwd)

# Measurement/formatting helpers (run_watched, peak_mib, fmt, cell, count_images, rc_text).
# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"

STAGES=(decode features matching adjust frame_total)
ROWS=()
mem_cap_kb=$(awk -v g="$STITCHER_MEM_GB" 'BEGIN { printf "%d", g * 1048576 }')

for flight in $FLIGHTS; do
  img_dir=$DATA_DIR/$flight/images
  fdir=$OUT_DIR/$flight
  mkdir -p "$fdir/uavmosaic"
  n_img=$(count_images "$img_dir")

  # ---- ours -------------------------------------------------------------------------------
  o_frames=$n_img o_reg="—" o_rms="—" o_wall="" o_stages="—" o_comp="—" o_rss="—"
  o_ok=0
  report=$fdir/uavmosaic/report.json
  rm -f "$report"  # never read a stale report from an earlier run into this OUT_DIR
  if [[ ! -d $img_dir ]]; then
    o_wall="failed: no $flight/images"
  elif [[ ! -x $OURS_BIN ]]; then
    o_wall="failed: not built ($OURS_BIN)"
  else
    log "$flight: uavmosaic-onboard ($n_img frames)"
    run_watched "$fdir/uavmosaic" 0 "$OURS_TIMEOUT_S" \
      "$OURS_BIN" --source "replay:$img_dir" --out "$fdir/uavmosaic" "${OURS_EXTRA[@]}"
    o_rss=$(peak_mib)
    if [[ $W_KILLED == timeout ]]; then
      o_wall="timeout at $OURS_TIMEOUT_S s"
    elif ((W_RC != 0)); then
      o_wall="failed: $(rc_text "$W_RC")"
    elif [[ ! -s $report ]]; then
      o_wall="failed: no report.json"
    elif ! jq -e 'type == "object"' "$report" >/dev/null 2>&1; then
      o_wall="failed: report.json is not a JSON object"
    else
      o_wall=$W_WALL_S o_ok=1
    fi
    ours_wall_s=$W_WALL_S
  fi
  r_frames="" r_reg="" r_rms="" r_hold="" r_comp="" r_rss="" r_st=""
  if [[ -s $report ]] && jq -e . "$report" >/dev/null 2>&1; then
    # \x1f as separator: unlike tab it is not IFS whitespace, so empty fields are not collapsed.
    IFS=$'\x1f' read -r r_frames r_reg r_rms r_hold r_comp r_rss r_st < <(jq -r --arg st "${STAGES[*]}" '
      [ (.frames_in // ""), (.registered // ""), (.residual_rms_px // ""), (.holdout_rms_px // ""),
        (.composite_ms // ""),
        (.peak_rss_mib // ""),
        ([ ($st | split(" "))[] as $k | (.stages_ms[$k].median // "-") | tostring ] | join(" ")) ]
      | map(tostring) | join("\u001f")' "$report") || true
    [[ -n ${r_frames:-} ]] && o_frames=$r_frames
    o_reg=$(cell "${r_reg:-—}")
    [[ -z $o_reg ]] && o_reg="—"
    o_rms="$(fmt "${r_rms:-}" 2) / $(fmt "${r_hold:-}" 2) ($(jq -r '.model // "?"' "$report"))"
    o_comp=$(fmt "${r_comp:-}" 2 1000)
    # The watchdog may miss a process that lives < 0.2 s; fall back to the program's own figure.
    [[ $o_rss == "—" ]] && o_rss=$(fmt "${r_rss:-}" 0)
    IFS=' ' read -r -a med <<<"$r_st"  # a missing stage is "-", so positions stay aligned
    parts=()
    for i in "${!STAGES[@]}"; do parts+=("$(fmt "${med[$i]:-}" 1)"); done
    o_stages=$(IFS=/; echo "${parts[*]}")
    o_stages=${o_stages//\// \/ }
  fi
  ROWS+=("| $flight | uavmosaic-onboard | $o_frames | $o_reg | $o_rms | $(cell "$o_wall") | $o_stages | $o_comp | $o_rss | — |")

  # ---- cv::Stitcher -----------------------------------------------------------------------
  s_frames=$n_img s_reg="—" s_wall="" s_rss="—" ratio="—"
  if [[ ! -d $img_dir ]]; then
    s_wall="failed: no $flight/images"
  elif [[ ! -x $STITCHER_BIN ]]; then
    s_wall="failed: not built ($STITCHER_BIN)"
  else
    log "$flight: cv::Stitcher SCANS (cap ${STITCHER_MEM_GB} GiB, ${STITCHER_TIMEOUT_S} s)"
    S_FRAMES=$n_img
    run_stitcher "$fdir" "$img_dir" "$STITCHER_TIMEOUT_S" "$mem_cap_kb" "$o_ok" "$ours_wall_s"
    s_frames=$S_FRAMES s_reg=$S_REG s_wall=$S_WALL s_rss=$S_RSS ratio=$S_RATIO
  fi
  ROWS+=("| $flight | cv::Stitcher SCANS | $s_frames | $s_reg | — | $(cell "$s_wall") | — | — | $s_rss | $ratio |")
done

cpu=$(awk -F': ' '/^model name/ { print $2; exit }' /proc/cpuinfo)
{
  echo "Real-flight benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc), CPU: ${cpu:-unknown}"
  echo
  echo "| flight | tool | frames | registered | residual / held-out RMS px (model) | wall s | per-frame ms (median: decode / features / matching / adjust / frame_total) | composite s | peak RSS MiB | stitcher wall / ours wall |"
  echo "|---|---|---:|---:|---:|---:|---|---:|---:|---:|"
  printf '%s\n' "${ROWS[@]}"
  echo
  echo "residual: transfer error of the adjusted correspondences (report.json residual_rms_px, working-resolution px); held-out: the same for up to 16 further inliers per edge that the adjustment never used (holdout_rms_px)." \
    "wall s: measured outside the process (load + work + write). peak RSS: max VmHWM polled every 0.2 s." \
    "cv::Stitcher caps: ${STITCHER_TIMEOUT_S} s, ${STITCHER_MEM_GB} GiB RSS (SIGKILL). 'registered' for cv::Stitcher = frames in its largest component."
} >"$OUT_DIR/table.md"

cp "$OUT_DIR/table.md" "$RESULTS_DIR/$STAMP-$(hostname).md"
cat "$OUT_DIR/table.md"
log "table: $OUT_DIR/table.md and $RESULTS_DIR/$STAMP-$(hostname).md"
