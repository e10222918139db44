#!/usr/bin/env bash
# stereo_middlebury.sh DATA_DIR [RUNS]
#
# Dense matcher (core/stereo SGM) vs OpenCV StereoSGBM (block 5, MODE_SGBM_3WAY, same numDisparities) on the six
# Middlebury pairs in DATA_DIR (e.g. ../shared/data/middlebury_stereo beside the project): bad-1, bad-2 (no disparity = wrong) and the
# median time of RUNS (default 5) interleaved runs. Writes $UAVM_RESULTS_DIR/stereo-middlebury-<date>-<host>.md and a
# colour-mapped disparity PNG of teddy (GT | ours | SGBM) beside it.
#
# Environment: UAVM_BUILD_DIR (default <repo>/build, needs target uavm-stereo-middlebury),
#              UAVM_RESULTS_DIR (default bench/results), EXTRA_ARGS (more options for the program, e.g. "--paths 8").
set -euo pipefail
export LC_ALL=C
SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -lt 1 || $# -gt 2 || $1 == -h || $1 == --help ]]; then
  sed -n '2,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
DATA_DIR=$(cd "$1" && pwd)
RUNS=${2:-5}
BUILD_DIR=${UAVM_BUILD_DIR:-$REPO/build}
RESULTS_DIR=${UAVM_RESULTS_DIR:-$REPO/bench/results}
BIN=$BUILD_DIR/bench/uavm-stereo-middlebury
[[ -x $BIN ]] || { echo "missing $BIN (ninja -C $BUILD_DIR uavm-stereo-middlebury)" >&2; exit 1; }
mkdir -p "$RESULTS_DIR"
NAME=stereo-middlebury-$(date +%Y%m%d-%H%M%S)-$(hostname -s 2>/dev/null || echo host)
OUT=$RESULTS_DIR/$NAME.md
PNG=$RESULTS_DIR/$NAME-teddy.png
{
  echo "# Dense stereo on Middlebury: core/stereo SGM vs OpenCV StereoSGBM"
  echo
  echo "$(date -u +%Y-%m-%dT%H:%M:%SZ), $(awk -F': ' '/^model name/ { print $2; exit }' /proc/cpuinfo), $(nproc) cores," \
       "load average before the run: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo "git $(git -C "$REPO" rev-parse --short HEAD 2>/dev/null || echo '?'); data $DATA_DIR; extra args: ${EXTRA_ARGS:-none}"
  echo
  echo "bad-T = % of pixels with known GT whose |disparity - GT| > T px; a pixel without disparity counts as wrong."
  echo "Ours: census 9x7 + gradient cost, SGM, LR check, equiangular sub-pixel fit, speckle filter, hole fill, 3x3 median."
  echo "SGBM: StereoSGBM(0, ndisp, 5, P1=8*3*25, P2=32*3*25, disp12MaxDiff=1, preFilterCap=63, uniqueness=10,"
  echo "speckle 100/32, MODE_SGBM_3WAY); invalid SGBM pixels count as wrong. Time: median of $RUNS interleaved runs."
  echo
  # shellcheck disable=SC2086
  "$BIN" "$DATA_DIR" --runs "$RUNS" --png "$PNG" ${EXTRA_ARGS:-}
  echo
  echo "Disparity image (teddy; GT | ours | SGBM, turbo colour map, black = none): $NAME-teddy.png"
} | tee "$OUT"
echo "wrote $OUT and $PNG" >&2
