#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/, clang, build directory build-fuzz/ or --build-dir) and runs each for a set
# number of executions on its corpus in fuzz/corpus/<target>/; prints target, executions, seconds, crashes.
#
#   scripts/fuzz.sh                      # CI: 20000 executions per target
#   scripts/fuzz.sh --seconds 120        # each target for 120 s (the full tier, scripts/test_full.sh)
#   scripts/fuzz.sh --runs 1000000       # the long run (bench/fuzz.sh)
#   scripts/fuzz.sh --runs 1000000 --minimize   # ... then merge what it found into fuzz/corpus/ (minimised)
#   scripts/fuzz.sh --target fuzz_config # one target (repeat --target for several)
#   scripts/fuzz.sh --skip fuzz_config   # every target but that one (the CI tier)
#   scripts/fuzz.sh --quick-build        # -O0 in build-fuzz-O0/: builds 2.5x faster, runs ~2x slower (the CI tier's
#                                        # 20000 executions cost less than the -O1 build would)
#
# New inputs of a run go to <build-dir>/fuzz-work/<target>/, not into the repository, unless --minimize. A crash
# leaves its input in <build-dir>/fuzz-artifacts/<target>/ and fails the script (exit 1); once fixed, add it to
# fuzz/regressions/<target>/ (run every time, never minimised away).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
RUNS=20000
SECONDS_EACH=0  # > 0: a time budget per target instead of a number of executions
BUILD_DIR=""
OPT=1
MINIMIZE=0
ONLY=()
SKIP=()
JOBS="${UAVM_JOBS:-2}"
while [ $# -gt 0 ]; do
  case "$1" in
    --runs) RUNS="$2"; shift 2 ;;
    --seconds) SECONDS_EACH="$2"; RUNS=-1; shift 2 ;;
    --build-dir) BUILD_DIR="$2"; shift 2 ;;
    --minimize) MINIMIZE=1; shift ;;
    --quick-build) OPT=0; shift ;;
    --target) ONLY+=("$2"); shift 2 ;;
    --skip) SKIP+=("$2"); shift 2 ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    *) echo "fuzz.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
if [ -z "$BUILD_DIR" ]; then
  BUILD_DIR="$ROOT/build-fuzz"
  [ "$OPT" = 0 ] && BUILD_DIR="$ROOT/build-fuzz-O0"
fi
TARGETS=(fuzz_config fuzz_metadata fuzz_transforms_csv fuzz_features_bin fuzz_edges_bin fuzz_journal)
if [ ${#ONLY[@]} -gt 0 ]; then TARGETS=("${ONLY[@]}"); fi
for skip in "${SKIP[@]}"; do
  for i in "${!TARGETS[@]}"; do [ "${TARGETS[$i]}" = "$skip" ] && unset "TARGETS[$i]"; done
done
TARGETS=("${TARGETS[@]}")

command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ not found (apt-get install clang)" >&2; exit 2; }
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  GEN=()
  command -v ninja >/dev/null && GEN=(-G Ninja)
  CC=clang CXX=clang++ cmake -S "$ROOT" -B "$BUILD_DIR" "${GEN[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O$OPT -gline-tables-only" -DUAVM_FUZZ=ON -DUAVM_BUILD_TESTS=OFF -DUAVM_BUILD_BENCH=OFF >/dev/null
fi
start_build=$(date +%s)
nice -n 10 cmake --build "$BUILD_DIR" -j "$JOBS" --target "${TARGETS[@]}" >"$BUILD_DIR/fuzz-build.log" 2>&1 ||
  { tail -40 "$BUILD_DIR/fuzz-build.log"; echo "fuzz.sh: build failed" >&2; exit 1; }
echo "fuzz.sh: build $(($(date +%s) - start_build)) s ($BUILD_DIR)"

# fuzz_one TARGET: runs one target; its table row goes to fuzz-row-TARGET, exit 1 when it found a crash.
fuzz_one() {
  local t="$1" corpus work artifacts log t0 status=0 secs execs crashes fresh regressions=()
  corpus="$ROOT/fuzz/corpus/$t"
  if [ -d "$ROOT/fuzz/regressions/$t" ]; then regressions=("$ROOT/fuzz/regressions/$t"); fi
  work="$BUILD_DIR/fuzz-work/$t"
  artifacts="$BUILD_DIR/fuzz-artifacts/$t"
  mkdir -p "$corpus" "$work" "$artifacts"
  rm -f "$artifacts"/*
  log="$BUILD_DIR/fuzz-$t.log"
  t0=$(date +%s%N)
  # -max_len: enough for a config or a small JPEG header with EXIF/XMP; -timeout: a hang is a bug too.
  nice -n 10 "$BUILD_DIR/fuzz/$t" -runs="$RUNS" -max_total_time="$SECONDS_EACH" -max_len=65536 -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$artifacts/" "$work" "$corpus" "${regressions[@]}" >"$log" 2>&1 || status=$?
  secs=$(awk -v a="$t0" -v b="$(date +%s%N)" 'BEGIN { printf "%.1f", (b - a) / 1e9 }')
  execs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -oE '[0-9]+$' || true)
  crashes=$(find "$artifacts" -type f | wc -l)
  if [ "$status" -ne 0 ] && [ "$crashes" -eq 0 ]; then crashes=1; fi
  printf '| %-20s | %11s | %7s | %7s |\n' "$t" "${execs:-?}" "$secs" "$crashes" >"$BUILD_DIR/fuzz-row-$t"
  if [ "$crashes" -ne 0 ]; then
    echo "---- $t failed (exit $status), last lines of $log:" >&2
    tail -30 "$log" >&2
    return 1
  elif [ "$MINIMIZE" -eq 1 ]; then
    # Keep only inputs that add coverage: merge the old corpus and this run's finds into a fresh folder.
    fresh="$BUILD_DIR/fuzz-merge/$t"
    rm -rf "$fresh" && mkdir -p "$fresh"
    "$BUILD_DIR/fuzz/$t" -merge=1 -max_len=65536 "$fresh" "$corpus" "$work" >>"$log" 2>&1
    rm -rf "$corpus" && mv "$fresh" "$corpus"
    rm -rf "$work"
  fi
}

# The targets $JOBS at a time (each libFuzzer run is one thread).
failed=0
running=0
for t in "${TARGETS[@]}"; do
  rm -f "$BUILD_DIR/fuzz-row-$t"
  if [ "$running" -ge "$JOBS" ]; then
    wait -n || failed=1
    running=$((running - 1))
  fi
  fuzz_one "$t" &
  running=$((running + 1))
done
while [ "$running" -gt 0 ]; do
  wait -n || failed=1
  running=$((running - 1))
done

echo
echo "| target               |  executions | seconds | crashes |"
echo "|----------------------|-------------|---------|---------|"
for t in "${TARGETS[@]}"; do cat "$BUILD_DIR/fuzz-row-$t" 2>/dev/null || printf '| %-20s | %11s |\n' "$t" "no result"; done
exit "$failed"
