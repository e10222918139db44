#!/usr/bin/env bash
# run.sh DATA_DIR [OUT_DIR]
#
# One benchmark: simulated flights with ground truth (bench/plans/sim_*.yaml over the full-resolution
# DATA_DIR/caliterra/images/IMG_9360.jpg) and the real flights (via bench/run_real.sh), uavmosaic-onboard
# vs OpenCV's cv::Stitcher, one markdown table (OUT_DIR/table.md and $RESULTS_DIR/<date>-<hostname>.md).
#
# Environment:
#   FLIGHTS_SIM            simulated plans (default "sim_easy sim_hard sim_long sim_tilt1 sim_tilt2"; "" = none)
#   FLIGHTS_REAL           real flight folders (default "brighton_beach caliterra"; "" = none)
#   QUICK=1                small versions of the sim plans (2 strips, 1 pass) for testing
#   SIM_DIR                where flights are generated (default OUT_DIR/sim; reused when gt.csv exists)
#   SIM_STITCHER_TIMEOUT_S cv::Stitcher wall cap on sim flights, s (default 300)
#   STITCHER_TIMEOUT_S     cv::Stitcher wall cap on real flights, s (default 600, run_real.sh)
#   STITCHER_MEM_GB        cv::Stitcher RSS cap, GiB (default 12)
#   OURS_TIMEOUT_S         wall cap for uavmosaic-onboard, s (default 0 = none)
#   OURS_ARGS              extra uavmosaic-onboard options, e.g. "--model affine" (also passed to run_real.sh)
#   UAVM_BUILD_DIR         build tree (default <repo>/build)
#   UAVM_RESULTS_DIR       where the dated table goes (default bench/results)
set -euo pipefail
export LC_ALL=C

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")

if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,21p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi

# shellcheck source=bench/lib.sh
source "$SCRIPT_DIR/lib.sh"

DATA_DIR=$(cd "$1" && pwd)
STAMP=$(date +%Y%m%d-%H%M%S)
RESULTS_DIR=${UAVM_RESULTS_DIR:-$SCRIPT_DIR/results}
OUT_DIR=${2:-$RESULTS_DIR/run-$STAMP}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
OURS_BIN=$BUILD/firmware_app/uavmosaic-onboard
read -r -a OURS_EXTRA <<<"${OURS_ARGS:-}"
SIM_BIN=$BUILD/tools/uavmosaic-sim
EVAL_BIN=$BUILD/tools/uavmosaic-eval
STITCHER_BIN=$BUILD/bench/uavm-stitcher-bench
SIM_STITCHER_TIMEOUT_S=${SIM_STITCHER_TIMEOUT_S:-300}
STITCHER_MEM_GB=${STITCHER_MEM_GB:-12}
OURS_TIMEOUT_S=${OURS_TIMEOUT_S:-0}
FLIGHTS_SIM=${FLIGHTS_SIM-sim_easy sim_hard sim_long sim_tilt1 sim_tilt2}
FLIGHTS_REAL=${FLIGHTS_REAL-brighton_beach caliterra}
QUICK=${QUICK:-0}
CANVAS=$DATA_DIR/caliterra/images/IMG_9360.jpg

log() { echo "[run] $*" >&2; }

command -v jq >/dev/null 2>&1 || { log "jq missing (apt-get install jq)"; exit 1; }
mkdir -p "$OUT_DIR" "$RESULTS_DIR"
OUT_DIR=$(cd "$OUT_DIR" && pwd)
SIM_DIR=${SIM_DIR:-$OUT_DIR/sim}
mkdir -p "$SIM_DIR"
mem_cap_kb=$(awk -v g="$STITCHER_MEM_GB" 'BEGIN { printf "%d", g * 1048576 }')
ROWS=()
NOTES=()

# stages REPORT: "frame_total / features" medians in ms from report.json, "—" when absent.
stages() {
  local ft fe
  IFS=' ' read -r ft fe < <(jq -r '[(.stages_ms.frame_total.median // "-"), (.stages_ms.features.median // "-")]
    | map(tostring) | join(" ")' "$1" 2>/dev/null || echo "- -")
  echo "$(fmt "${ft:-}" 1) / $(fmt "${fe:-}" 1)"
}

# image_score MOSAIC PREFIX: "median / p90" canvas px from `uavmosaic-eval image`, or a short failure note.
image_score() {
  local mosaic=$1 prefix=$2
  [[ -s $mosaic ]] || { echo "—"; return 0; }
  if "$EVAL_BIN" image --mosaic "$mosaic" --canvas "$CANVAS" --json "$prefix.json" >"$prefix.log" 2>&1 &&
    [[ -s $prefix.json ]]; then
    jq -r '"\(.median_px) \(.p90_px)"' "$prefix.json" | { read -r m p; echo "$(fmt "$m" 2) / $(fmt "$p" 2)"; }
  else
    echo "score failed"
  fi
}

# ---- simulated flights ----------------------------------------------------------------------
for name in $FLIGHTS_SIM; do
  plan=$SCRIPT_DIR/plans/$name.yaml
  label=$name
  fdir=$OUT_DIR/$name
  flight=$SIM_DIR/$name
  if [[ $QUICK == 1 ]]; then
    label=$name-quick fdir=$OUT_DIR/$name-quick flight=$SIM_DIR/$name-quick
  fi
  mkdir -p "$fdir/uavmosaic" "$flight"
  if [[ ! -f $plan ]]; then
    ROWS+=("| $label | — | — | — | failed: no plan $plan | — | — | — | — | — | — | — |")
    continue
  fi
  # ---- flight -----------------------------------------------------------------------------
  if [[ ! -s $flight/gt.csv ]]; then
    use_plan=$plan
    if [[ $QUICK == 1 ]]; then  # fewer strips, one pass
      use_plan=$flight.quick.yaml
      grep -v -E '^(strips|passes):' "$plan" >"$use_plan"
      printf 'strips: 2\npasses: 1\n' >>"$use_plan"
    fi
    log "$label: simulating ($use_plan)"
    if ! "$SIM_BIN" --plan "$use_plan" --canvas "$CANVAS" --out "$flight" >"$flight.sim.log" 2>&1; then
      log "$label: simulation failed, see $flight.sim.log"
      ROWS+=("| $label | — | — | — | failed: simulation ($(cell "$(tail -n 1 "$flight.sim.log")")) | — | — | — | — | — | — | — |")
      continue
    fi
  fi
  if [[ -f $flight.sim.log ]] && grep -q 'shrunk' "$flight.sim.log"; then
    NOTES+=("$label: $(grep -o 'sim plan shrunk.*' "$flight.sim.log" | head -n 1)")
  fi
  img_dir=$flight/images
  n_img=$(count_images "$img_dir")

  # ---- ours -------------------------------------------------------------------------------
  report=$fdir/uavmosaic/report.json
  rm -f "$report" "$fdir/eval.json" "$fdir"/score_*.json
  o_ok=0 o_wall="" o_rss="—" o_reg="—" o_err="—" o_floor="—" o_drift="—" o_score="—" o_st="— / —"
  o_frames=$n_img ours_wall_s=0
  log "$label: uavmosaic-onboard ($n_img frames)"
  run_watched "$fdir/uavmosaic" 0 "$OURS_TIMEOUT_S" \
    "$OURS_BIN" --source "replay:$img_dir" --out "$fdir/uavmosaic" "${OURS_EXTRA[@]}"
  o_rss=$(peak_mib)
  ours_wall_s=$W_WALL_S
  if [[ $W_KILLED == timeout ]]; then
    o_wall="timeout at $OURS_TIMEOUT_S s"
  elif ((W_RC != 0)); then
    o_wall="failed: $(rc_text "$W_RC")"
  elif ! jq -e 'type == "object"' "$report" >/dev/null 2>&1; then
    o_wall="failed: no valid report.json"
  else
    o_wall=$W_WALL_S o_ok=1
  fi
  if [[ -s $report ]] && jq -e . "$report" >/dev/null 2>&1; then
    o_st=$(stages "$report")
    [[ $o_rss == "—" ]] && o_rss=$(fmt "$(jq -r '.peak_rss_mib // ""' "$report")" 0)
  fi
  if [[ -s $fdir/uavmosaic/transforms.csv ]]; then
    if "$EVAL_BIN" --session "$fdir/uavmosaic" --gt "$flight/gt.csv" --json "$fdir/eval.json" \
      >"$fdir/eval.log" 2>&1 && [[ -s $fdir/eval.json ]]; then
      IFS=$'\x1f' read -r e_fr e_reg e_share e_rms e_max f_rms f_max d_first d_last d_slope < <(jq -r '
        [.frames, .registered, .registered_share, .rms_px, .max_px, .affine_floor_rms_px, .affine_floor_max_px,
         .drift.first_third_rms_px, .drift.last_third_rms_px, .drift.slope_px_per_kpx]
        | map(tostring) | join("\u001f")' "$fdir/eval.json")
      o_frames=$e_fr
      o_reg="$e_reg ($(fmt "$e_share" 1 0.01) %)"
      o_err="$(fmt "$e_rms" 3) / $(fmt "$e_max" 3)"
      o_floor="$(fmt "$f_rms" 3) / $(fmt "$f_max" 3)"
      o_drift="$(fmt "$d_first" 3) → $(fmt "$d_last" 3) ($(fmt "$d_slope" 3)/kpx)"
    else
      o_err="eval failed: $(cell "$(tail -n 1 "$fdir/eval.log")")"
    fi
  fi
  # Score the full-resolution mosaic when the scorer can read it, else the quick look.
  mosaic=$fdir/uavmosaic/mosaic.tif
  [[ -s $mosaic ]] || mosaic=$fdir/uavmosaic/mosaic.png
  o_score=$(image_score "$mosaic" "$fdir/score_ours")
  if [[ $o_score == "score failed" && $mosaic == *.tif ]]; then
    o_score=$(image_score "$fdir/uavmosaic/mosaic.png" "$fdir/score_ours")
  fi
  ROWS+=("| $label | uavmosaic-onboard | $o_frames | $o_reg | $o_err | $o_drift | $o_floor | $o_score | $(cell "$o_wall") | $o_st | $o_rss | — |")

  # ---- cv::Stitcher -----------------------------------------------------------------------
  log "$label: cv::Stitcher SCANS (cap ${STITCHER_MEM_GB} GiB, ${SIM_STITCHER_TIMEOUT_S} s)"
  S_FRAMES=$n_img
  run_stitcher "$fdir" "$img_dir" "$SIM_STITCHER_TIMEOUT_S" "$mem_cap_kb" "$o_ok" "$ours_wall_s"
  s_frames=$S_FRAMES s_reg=$S_REG s_wall=$S_WALL s_rss=$S_RSS ratio=$S_RATIO s_score="—"
  if [[ $S_STATUS == ok && -z $W_KILLED ]]; then
    s_score=$(image_score "$fdir/stitcher.png" "$fdir/score_stitcher")
  fi
  ROWS+=("| $label | cv::Stitcher SCANS | $s_frames | $s_reg | — | — | — | $s_score | $(cell "$s_wall") | — | $s_rss | $ratio |")
done

# ---- real flights: bench/run_real.sh, then its table and report.json are read back -----------
if [[ -n ${FLIGHTS_REAL// /} ]]; then
  real_out=$OUT_DIR/real
  mkdir -p "$real_out"
  log "real flights ($FLIGHTS_REAL) via run_real.sh"
  if ! FLIGHTS=$FLIGHTS_REAL STITCHER_MEM_GB=$STITCHER_MEM_GB OURS_TIMEOUT_S=$OURS_TIMEOUT_S \
    UAVM_BUILD_DIR=$BUILD UAVM_RESULTS_DIR=$real_out \
    "$SCRIPT_DIR/run_real.sh" "$DATA_DIR" "$real_out" >"$real_out/run_real.stdout" 2>"$real_out/run_real.stderr"; then
    log "run_real.sh failed, see $real_out/run_real.stderr"
  fi
  for flight in $FLIGHTS_REAL; do
    # run_real.sh columns: flight | tool | frames | registered | residual | wall | stages | composite | rss | ratio
    while IFS= read -r line; do
      IFS=$'\x1f' read -r _ f tool frames reg res wall _st _comp rss ratio _ < <(
        sed 's/ *| */\x1f/g' <<<"$line")
      [[ $f == "$flight" ]] || continue
      if [[ $tool == uavmosaic-onboard ]]; then
        st=$(stages "$real_out/$flight/uavmosaic/report.json")
        [[ $res != "—" ]] && res="residual / held-out $res (report.json, work px)"
        ROWS+=("| $flight (real) | $tool | $frames | $reg | $res | — | — | — | $wall | $st | $rss | $ratio |")
      else
        ROWS+=("| $flight (real) | $tool | $frames | $reg | — | — | — | — | $wall | — | $rss | $ratio |")
      fi
    done < <(grep "^| $flight |" "$real_out/table.md" 2>/dev/null || true)
    grep -q "^| $flight |" "$real_out/table.md" 2>/dev/null ||
      ROWS+=("| $flight (real) | — | — | — | failed: run_real.sh gave no row | — | — | — | — | — | — | — |")
  done
fi

{
  echo "uavmosaic benchmark, $(date '+%Y-%m-%d %H:%M:%S %z'), nproc $(nproc), CPU: $(cpu_model || echo unknown)$([[ $QUICK == 1 ]] && echo ', QUICK=1 (small sim plans)')"
  echo
  echo "| flight | tool | frames | registered | error RMS / max px | error drift (first → last third RMS, slope) | affine floor RMS / max px | image score median / p90 (canvas px) | wall s | per-frame ms (median frame_total / features) | peak RSS MiB | stitcher wall / ours wall |"
  echo "|---|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|"
  printf '%s\n' "${ROWS[@]}"
  echo
  echo "Sim flights: plans bench/plans/<flight>.yaml over $(basename "$CANVAS") (4000x3000); error = uavmosaic-eval grid error of every registered frame vs. ground truth, in original frame px, after one global mosaic→canvas homography; affine floor = the same for the best per-frame affine (what an affine model cannot beat). Real flights: error = residual_rms_px / holdout_rms_px from report.json (transfer error of the adjusted matches / of held-out matches the adjustment never used, working resolution px; no ground truth)."
  echo "image score: \`uavmosaic-eval image\` (SIFT + RANSAC affine of the mosaic to the canvas; ours scored on mosaic.tif, default mosaic scale). wall s measured outside the process (load + work + write); peak RSS = max VmHWM polled every 0.2 s."
  echo "cv::Stitcher caps: sim ${SIM_STITCHER_TIMEOUT_S} s, real ${STITCHER_TIMEOUT_S:-600} s, ${STITCHER_MEM_GB} GiB RSS (SIGKILL); ≥ ratio = stitcher was killed. 'registered' for cv::Stitcher = frames in its largest component."
  for n in "${NOTES[@]}"; do echo "Note: $n"; done
} >"$OUT_DIR/table.md"

cp "$OUT_DIR/table.md" "$RESULTS_DIR/$STAMP-$(hostname).md"
cat "$OUT_DIR/table.md"
log "table: $OUT_DIR/table.md and $RESULTS_DIR/$STAMP-$(hostname).md"
