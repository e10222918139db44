#!/usr/bin/env bash
# instructions.sh [OUT_DIR]
#
# Instruction counts of the per-frame stages (issue 23's aarch64 estimate on paper), without hardware counters
# (this VM has none: `perf stat -e instructions` says "not supported"):
#   x86-64  : valgrind --tool=callgrind on build/bench/uavm-micro-bench, one process for all stages; callgrind dumps
#             right after benchmark::State::StartKeepRunning and right before FinishKeepRunning, so each benchmark's
#             timed loop is one dump (exact, no start-up or set-up in it), divided by its iterations (from the JSON).
#   aarch64 : the cross-built micro-bench (build-aarch64, generic ARMv8-A -O3) under qemu-aarch64 with a small TCG
#             plugin that counts executed guest instructions (built here from an inline C file: Debian 12 ships no
#             QEMU plugins). The plugin also prints the count at each clock_gettime of a CPU-time clock; Google
#             Benchmark's timer reads one when a timed loop starts and when it stops, so the marks in pairs bracket the
#             loops, the same regions as the callgrind dumps. One process for all stages, like x86-64.
#   Both run with OPENCV_FOR_THREADS_NUM=1 (counts do not depend on threads; it keeps every count on one thread).
#   12 MP decode: the same, with UAVM_MICRO_IMAGES=$DATA/caliterra/images (4000x3000 photos), BM_JpegDecode/1 and /4.
#   Whole onboard run (optional, WHOLE=1): the default run on caliterra_small counted end to end under callgrind
#   (x86-64) and under qemu-aarch64 with the plugin in thread-safe mode (aarch64 build-aarch64 binary).
# A72 / A76 ms columns: instructions / (assumed IPC x clock); the IPC per stage type is in IPC_* below (nominal
# values; bench/results/aarch64-estimate-*.md gives the ranges and where they come from).
# Prints one markdown table; also saved to OUT_DIR/table.md.
#
# Environment:
#   UAVM_BUILD_DIR          x86-64 build (default <repo>/build); needs bench/uavm-micro-bench
#   UAVM_AARCH64_BUILD_DIR  aarch64 build (default <repo>/build-aarch64); needs bench/uavm-micro-bench (configure it
#                           with -DUAVM_BUILD_BENCH=ON, then `ninja -j1 uavm-micro-bench`); skipped when missing
#   UAVM_SYSROOT            arm64 sysroot for qemu -L (default: scripts/make_sysroot.sh's, under $UAVM_CACHE_DIR)
#   DATA                    data folder (default ../shared/data beside the clone), for the 12 MP photos and the whole run
#   WHOLE                   1 = also count the whole onboard run (slow: callgrind took ~2 min per frame here, so ~40
#                           min; aarch64 qemu ~15 min); x86 = only the x86-64 one
#   QEMU_CPU                CPU model qemu-aarch64 shows the program (default cortex-a72, the Pi 4's ARMv8.0-A: OpenCV
#                           and glibc pick their code paths from it; qemu's own default "max" gave SIFT/3 2 % more)
#   A72_GHZ / A76_GHZ       clocks (default 1.5 / 2.4)
#   REUSE                   1 = keep the counts already in OUT_DIR (*.loops, *.json) and only redo the tables
#   STAGES                  micro-bench filter of the stages counted (default: every stage of the table; e.g.
#                           'BM_SiftExtract/1/0/' for ours' SIFT alone: the other rows are then empty)
#   DECODE_12MP             0 = skip the 12 MP decode counts (default 1)
#   PROFILE                 1 = also where ours' SIFT spends its aarch64 instructions: one BM_SiftExtract/1/0 process
#                           under the plugin's per-block counts, summed per function of the micro-bench (set-up and
#                           iterations included: read the shares), to OUT_DIR/a64_profile.md
set -euo pipefail
export LC_ALL=C

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(dirname "$SCRIPT_DIR")
if [[ $# -gt 1 || ${1:-} == -h || ${1:-} == --help ]]; then
  sed -n '2,36p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
OUT_DIR=${1:-/tmp/uavm-instructions-$(date +%Y%m%d-%H%M%S)}
BUILD=${UAVM_BUILD_DIR:-$REPO/build}
A64_BUILD=${UAVM_AARCH64_BUILD_DIR:-$REPO/build-aarch64}
# The sysroot scripts/make_sysroot.sh makes (same default: the cache directory outside the clone).
SYSROOT=${UAVM_SYSROOT:-${UAVM_CACHE_DIR:-/var/cache/uavmosaic}/sysroot-arm64-bookworm}
DATA=${DATA:-$REPO/../shared/data}  # ../shared beside the clone, as in CI
WHOLE=${WHOLE:-0}
REUSE=${REUSE:-0}
export QEMU_CPU=${QEMU_CPU:-cortex-a72}
A72_GHZ=${A72_GHZ:-1.5}
A76_GHZ=${A76_GHZ:-2.4}
# Nominal IPC per stage type (A72 / A76); row() reads them by name. The per-frame section below has the ranges.
# shellcheck disable=SC2034
{
  IPC_SIMD_A72=1.0 IPC_SIMD_A76=1.8       # SIFT filters and descriptors, JPEG IDCT/colour (NEON, streaming)
  IPC_BRANCHY_A72=0.7 IPC_BRANCHY_A76=1.3 # descriptor index (tree/hash, cache misses), PNG deflate
  IPC_SCALAR_A72=1.1 IPC_SCALAR_A76=2.0   # RANSAC (small dense float work in L1)
}
mkdir -p "$OUT_DIR"
export OPENCV_FOR_THREADS_NUM=1
RUN=(nice -n 10)

X86_BIN=$BUILD/bench/uavm-micro-bench
A64_BIN=$A64_BUILD/bench/uavm-micro-bench
[[ -x $X86_BIN ]] || { echo "no $X86_BIN" >&2; exit 1; }
command -v valgrind >/dev/null || { echo "valgrind missing: apt-get install -y valgrind" >&2; exit 1; }

# --- x86-64: callgrind, one dump per timed loop -------------------------------------------------------------------
# loops_tsv NAME: OUT_DIR/NAME.tsv (benchmark name, instructions per iteration) from NAME.loops (instructions of each
# timed loop, in run order) and NAME.json (the runs and their iteration counts). The iteration count is the first
# "iterations" of each run: jq would return the last, and BM_RansacAffine has a user counter of that name.
loops_tsv() {
  local name=$1
  awk '/"name":/ { n = $0; sub(/.*"name": "/, "", n); sub(/",.*/, "", n); got = 0 }
    /"run_type":/ { it = ($0 ~ /"iteration"/) }
    /"iterations":/ && !got { got = 1; v = $2; sub(/,/, "", v); if (it) print n "\t" v }' \
    "$OUT_DIR/$name.json" >"$OUT_DIR/$name.iters"
  if [[ $(wc -l <"$OUT_DIR/$name.loops") != $(wc -l <"$OUT_DIR/$name.iters") ]]; then
    echo "$name: $(wc -l <"$OUT_DIR/$name.loops") timed loops for $(wc -l <"$OUT_DIR/$name.iters") runs" >&2
    exit 1
  fi
  paste "$OUT_DIR/$name.iters" "$OUT_DIR/$name.loops" | awk -F'\t' '{ printf "%s\t%.0f\n", $1, $3 / $2 }' \
    >"$OUT_DIR/$name.tsv"
}
# callgrind_loops NAME [ENV...] -- FILTER: writes OUT_DIR/NAME.tsv (benchmark name, instructions per iteration).
callgrind_loops() {
  local name=$1 filter=$2
  shift 2
  if [[ $REUSE == 1 && -s $OUT_DIR/$name.loops ]]; then loops_tsv "$name"; return 0; fi
  rm -f "$OUT_DIR/$name.cg"*
  env "$@" "${RUN[@]}" valgrind --tool=callgrind --dump-instr=no \
    --dump-after='benchmark::State::StartKeepRunning*' --dump-before='benchmark::State::FinishKeepRunning*' \
    --callgrind-out-file="$OUT_DIR/$name.cg" "$X86_BIN" --benchmark_filter="$filter" \
    --benchmark_min_time=0.000001 --benchmark_format=json --benchmark_out="$OUT_DIR/$name.json" \
    >"$OUT_DIR/$name.stdout" 2>"$OUT_DIR/$name.stderr"
  # Loop dumps in order (the dump files are numbered in time order).
  local f
  # shellcheck disable=SC2012 # our own numbered files
  for f in $(ls "$OUT_DIR/$name.cg".* | awk -F. '{ print $NF "\t" $0 }' | sort -n | cut -f2); do
    grep -q '^desc: Trigger: --dump-before=benchmark::State::FinishKeepRunning' "$f" &&
      awk '/^totals:/ { print $2 }' "$f"
  done >"$OUT_DIR/$name.loops"
  loops_tsv "$name"
}

echo "x86-64 callgrind: micro-bench stages (1000x750 frames) ..." >&2
STAGES=${STAGES:-'BM_(SiftExtract|IndexBuild|IndexQuery|MatchPair/[01]|RansacAffine|JpegDecode|TilePngEncode/1)/'}
DECODE_12MP=${DECODE_12MP:-1}
callgrind_loops x86 "$STAGES"
if [[ $DECODE_12MP == 1 ]]; then
  echo "x86-64 callgrind: 12 MP JPEG decode ..." >&2
  callgrind_loops x86_12mp 'BM_JpegDecode/[14]/' UAVM_MICRO_IMAGES="$DATA/caliterra/images"
else
  : >"$OUT_DIR/x86_12mp.tsv"
fi

# x86 VALUE_OF BENCH_PREFIX [FILE]: instructions per iteration of the first benchmark whose name starts so.
x86() { awk -F'\t' -v p="$1" 'index($1, p) == 1 { print $2; exit }' "$OUT_DIR/${2:-x86}.tsv"; }

# --- aarch64: qemu-aarch64 + instruction-count plugin, repetition difference --------------------------------------
PLUGIN=$OUT_DIR/libinsncount.so
cat >"$OUT_DIR/insncount.c" <<'EOF'
/* Minimal QEMU 7.2 TCG plugin (plugin API version 1): counts guest instructions executed and prints
   "insns N" at exit. Default: one inline add per translation block (fast; exact for one busy thread).
   "mt=on": an atomic add in a per-block callback (exact with several guest threads, slower).
   The few API declarations are written out by hand: Debian 12 ships neither qemu-plugin.h nor the contrib plugins. */
#include <stdint.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
typedef struct qemu_info_t qemu_info_t;
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 };
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS };
typedef void (*tb_trans_cb)(qemu_plugin_id_t, struct qemu_plugin_tb *);
typedef void (*udata_cb)(qemu_plugin_id_t, void *);
typedef void (*vcpu_udata_cb)(unsigned int, void *);
void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t, tb_trans_cb);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *);
void qemu_plugin_register_vcpu_tb_exec_inline(struct qemu_plugin_tb *, enum qemu_plugin_op, void *, uint64_t);
void qemu_plugin_register_vcpu_tb_exec_cb(struct qemu_plugin_tb *, vcpu_udata_cb, enum qemu_plugin_cb_flags, void *);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t, udata_cb, void *);
void qemu_plugin_outs(const char *);
typedef void (*syscall_cb)(qemu_plugin_id_t, unsigned int, int64_t, uint64_t, uint64_t, uint64_t, uint64_t, uint64_t,
                           uint64_t, uint64_t, uint64_t);
void qemu_plugin_register_vcpu_syscall_cb(qemu_plugin_id_t, syscall_cb);
__attribute__((visibility("default"))) int qemu_plugin_version = 1;
static uint64_t insns;
static int mt, marks;
/* "profile=FILE": executions of every translation block, written at exit as "VADDR INSNS EXECUTIONS" lines (guest
   addresses; a symbol table turns them into instructions per function). One busy thread: inline adds. */
uint64_t qemu_plugin_tb_vaddr(const struct qemu_plugin_tb *);
struct block { uint64_t vaddr, insns, executions; };
enum { kMaxBlocks = 1 << 20 };
static struct block *blocks;
static uint64_t n_blocks;
static char profile[4096];
/* "marks=on": prints "mark CLOCK N" at every clock_gettime of a CPU-time clock (CLOCK_PROCESS_CPUTIME_ID = 2,
   CLOCK_THREAD_CPUTIME_ID = 3), N = instructions so far. Google Benchmark reads one at the start and at the end of
   each timed loop (its timer), so consecutive pairs bracket the loops. qemu-user 7.2 has no vDSO: these are real
   system calls (aarch64 number 113, x86-64 228). */
static void on_syscall(qemu_plugin_id_t id, unsigned int vcpu, int64_t num, uint64_t a1, uint64_t a2, uint64_t a3,
                       uint64_t a4, uint64_t a5, uint64_t a6, uint64_t a7, uint64_t a8) {
  (void)id; (void)vcpu; (void)a2; (void)a3; (void)a4; (void)a5; (void)a6; (void)a7; (void)a8;
  if ((num == 113 || num == 228) && (a1 == 2 || a1 == 3)) {
    char buf[64];
    snprintf(buf, sizeof buf, "mark %llu %llu\n", (unsigned long long)a1,
             (unsigned long long)__atomic_load_n(&insns, __ATOMIC_RELAXED));
    qemu_plugin_outs(buf);
  }
}
static void on_exec(unsigned int vcpu, void *n) {
  (void)vcpu;
  __atomic_fetch_add(&insns, (uint64_t)(uintptr_t)n, __ATOMIC_RELAXED);
}
static void on_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
  (void)id;
  const size_t n = qemu_plugin_tb_n_insns(tb);
  if (blocks && n_blocks < kMaxBlocks) {
    struct block *b = &blocks[n_blocks++];
    b->vaddr = qemu_plugin_tb_vaddr(tb);
    b->insns = n;
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &b->executions, 1);
  }
  if (mt)
    qemu_plugin_register_vcpu_tb_exec_cb(tb, on_exec, QEMU_PLUGIN_CB_NO_REGS, (void *)(uintptr_t)n);
  else
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &insns, n);
}
static void at_exit(qemu_plugin_id_t id, void *p) {
  (void)id; (void)p;
  char buf[64];
  snprintf(buf, sizeof buf, "insns %llu\n", (unsigned long long)__atomic_load_n(&insns, __ATOMIC_RELAXED));
  qemu_plugin_outs(buf);
  FILE *f = blocks ? fopen(profile, "w") : NULL;
  if (!f) return;
  if (n_blocks == kMaxBlocks) qemu_plugin_outs("profile: block table full, later blocks not counted\n");
  for (uint64_t i = 0; i < n_blocks; ++i)
    if (blocks[i].executions)
      fprintf(f, "%llx %llu %llu\n", (unsigned long long)blocks[i].vaddr, (unsigned long long)blocks[i].insns,
              (unsigned long long)blocks[i].executions);
  fclose(f);
}
__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info,
                                                                int argc, char **argv) {
  (void)info;
  for (int i = 0; i < argc; ++i) {
    mt |= strcmp(argv[i], "mt=on") == 0;
    marks |= strcmp(argv[i], "marks=on") == 0;
    if (strncmp(argv[i], "profile=", 8) == 0) {
      snprintf(profile, sizeof profile, "%s", argv[i] + 8);
      blocks = calloc(kMaxBlocks, sizeof *blocks);
    }
  }
  qemu_plugin_register_vcpu_tb_trans_cb(id, on_trans);
  if (marks) qemu_plugin_register_vcpu_syscall_cb(id, on_syscall);
  qemu_plugin_register_atexit_cb(id, at_exit, NULL);
  return 0;
}
EOF
gcc -O2 -shared -fPIC -o "$PLUGIN" "$OUT_DIR/insncount.c"

# qemu_count LOG PLUGIN_ARGS CMD...: guest instructions of the whole process (qemu-aarch64 + the plugin).
qemu_count() {
  local log=$1 args=$2
  shift 2
  "${RUN[@]}" qemu-aarch64 -L "$SYSROOT" -plugin "$PLUGIN$args" -d plugin -D "$log" "$@" >"$log.stdout" 2>"$log.stderr"
  awk '/^insns/ { print $2 }' "$log"
}
# qemu_loops NAME FILTER [ENV...]: like callgrind_loops, for the aarch64 micro-bench: the plugin's CPU-clock marks
# in pairs bracket each timed loop.
qemu_loops() {
  local name=$1 filter=$2
  shift 2
  if [[ $REUSE == 1 && -s $OUT_DIR/$name.loops ]]; then loops_tsv "$name"; return 0; fi
  (
    # shellcheck disable=SC2163 # exports the VAR=value arguments
    if (($#)); then export "$@"; fi
    qemu_count "$OUT_DIR/$name.log" ',marks=on' "$A64_BIN" --benchmark_filter="$filter" \
      --benchmark_min_time=0.000001 --benchmark_format=json --benchmark_out="$OUT_DIR/$name.json" >/dev/null
  )
  awk '/^mark/ { if (n++ % 2 == 0) s = $3; else print $3 - s }' "$OUT_DIR/$name.log" >"$OUT_DIR/$name.loops"
  loops_tsv "$name"
}

HAVE_A64=0
if [[ -x $A64_BIN ]] && command -v qemu-aarch64 >/dev/null; then
  HAVE_A64=1
  echo "aarch64 qemu: micro-bench stages (1000x750 frames) ..." >&2
  qemu_loops a64 "$STAGES"
  if [[ $DECODE_12MP == 1 ]]; then
    echo "aarch64 qemu: 12 MP JPEG decode ..." >&2
    qemu_loops a64_12mp 'BM_JpegDecode/[14]/' UAVM_MICRO_IMAGES="$DATA/caliterra/images"
  else
    : >"$OUT_DIR/a64_12mp.tsv"
  fi
else
  echo "no aarch64 micro-bench at $A64_BIN (or no qemu-aarch64): aarch64 column estimated as 1.0 x x86-64" >&2
fi
# a64 BENCH_PREFIX [FILE]: as x86, for aarch64 ("" when not measured).
a64() { if [[ $HAVE_A64 == 1 ]]; then x86 "$1" "${2:-a64}"; fi; }

# --- table --------------------------------------------------------------------------------------------------------
# row LABEL X86 A64 TYPE
row() {
  local label=$1 x=$2 a=${3:-} type=$4 ia72 ia76
  eval "ia72=\$IPC_${type}_A72 ia76=\$IPC_${type}_A76"
  awk -v l="$label" -v x="$x" -v a="$a" -v i72="$ia72" -v i76="$ia76" -v f72="$A72_GHZ" -v f76="$A76_GHZ" -v t="$type" '
    BEGIN {
      src = (a == "") ? "est." : "meas."
      if (a == "") a = x * 1.0
      printf "| %s | %s | %s (%s) | %.2f | %s | %s | %s |\n", l, n(x), n(a), src, a / x,
        ms(a / (i72 * f72 * 1e6)), ms(a / (i76 * f76 * 1e6)), tolower(t) " (" i72 " / " i76 ")"
    }
    function n(v) { return v >= 1e6 ? sprintf("%.1f M", v / 1e6) : sprintf("%.1f k", v / 1e3) }
    function ms(v) { return v >= 100 ? sprintf("%.0f", v) : v >= 1 ? sprintf("%.1f", v) : sprintf("%.3f", v) }'
}
{
  echo "| stage (one call) | x86-64 instructions (callgrind) | aarch64 instructions (meas. = qemu plugin; est. = x86 x 1.0) | a64/x86 | A72 ms @ ${A72_GHZ} GHz | A76 ms @ ${A76_GHZ} GHz | IPC type (A72 / A76) |"
  echo "|---|---:|---:|---:|---:|---:|---|"
  row "SIFT whole frame, ours (BM_SiftExtract/1/0) — the default plan" "$(x86 BM_SiftExtract/1/0/)" \
    "$(a64 BM_SiftExtract/1/0/)" SIMD
  row "SIFT 2 bands, ours (BM_SiftExtract/2/0)" "$(x86 BM_SiftExtract/2/0/)" "$(a64 BM_SiftExtract/2/0/)" SIMD
  row "SIFT whole frame, OpenCV 4.6 (BM_SiftExtract/1/1)" "$(x86 BM_SiftExtract/1/1/)" "$(a64 BM_SiftExtract/1/1/)" SIMD
  row "SIFT 3 bands, OpenCV 4.6 (BM_SiftExtract/3/1) — the plan before issue 40" "$(x86 BM_SiftExtract/3/1/)" \
    "$(a64 BM_SiftExtract/3/1/)" SIMD
  row "descriptor index build (BM_IndexBuild)" "$(x86 BM_IndexBuild/)" "$(a64 BM_IndexBuild/)" BRANCHY
  row "index query, all points (BM_IndexQuery)" "$(x86 BM_IndexQuery/)" "$(a64 BM_IndexQuery/)" BRANCHY
  row "pair match unguided (BM_MatchPair/0)" "$(x86 BM_MatchPair/0/)" "$(a64 BM_MatchPair/0/)" BRANCHY
  row "pair match guided, capped (BM_MatchPair/1)" "$(x86 BM_MatchPair/1/)" "$(a64 BM_MatchPair/1/)" BRANCHY
  row "RANSAC affine (BM_RansacAffine)" "$(x86 BM_RansacAffine/)" "$(a64 BM_RansacAffine/)" SCALAR
  row "JPEG decode 1000x750 full (BM_JpegDecode/1)" "$(x86 BM_JpegDecode/1/)" "$(a64 BM_JpegDecode/1/)" SIMD
  row "JPEG decode 1000x750 1/2 (BM_JpegDecode/2)" "$(x86 BM_JpegDecode/2/)" "$(a64 BM_JpegDecode/2/)" SIMD
  row "JPEG decode 1000x750 1/4 (BM_JpegDecode/4)" "$(x86 BM_JpegDecode/4/)" "$(a64 BM_JpegDecode/4/)" SIMD
  row "JPEG decode 12 MP full (BM_JpegDecode/1, caliterra)" "$(x86 BM_JpegDecode/1/ x86_12mp)" "$(a64 BM_JpegDecode/1/ a64_12mp)" SIMD
  row "JPEG decode 12 MP 1/4 (BM_JpegDecode/4, caliterra)" "$(x86 BM_JpegDecode/4/ x86_12mp)" "$(a64 BM_JpegDecode/4/ a64_12mp)" SIMD
  row "PNG tile 256 px level 1 (BM_TilePngEncode/1)" "$(x86 BM_TilePngEncode/1/)" "$(a64 BM_TilePngEncode/1/)" BRANCHY
} >"$OUT_DIR/table.md"

# --- per frame and frames/s --------------------------------------------------------------------------------------
# In-flight work per frame of the default onboard run at the working size (1000x750, sift_bands 1 with our SIFT):
#   decode + SIFT (whole frame) + one index build + EDGES_PER_FRAME pair matches (guided; the pessimistic case unguided)
#   + OTHER_SHARE for the stages the micro-bench lacks (prepare, preview, adjust, live georef).
# Defaults from the caliterra_small run of 2026-11-24 (report.json: 67 edges / 20 frames; stage medians: prepare +
# preview + adjust + georef = 6.4 % of decode + features + matching).
# Cases (optimistic / nominal / pessimistic): IPC per type, effective cores out of the 2 given to the mapper, and a
# memory-stall surcharge (Pi 4: 32-bit LPDDR4, ~4 GB/s sustained; Pi 5 about twice that).
EDGES_PER_FRAME=${EDGES_PER_FRAME:-3.35}
OTHER_SHARE=${OTHER_SHARE:-0.064}
{
  echo ""
  echo "Per frame (aarch64 instructions; \"est.\" = x86-64 count used) and frames/s, optimistic / nominal / pessimistic:"
  echo ""
  echo "| frame source | decode | SIFT | matching (guided; unguided) | other | total | A72 @ ${A72_GHZ} GHz frames/s | A76 @ ${A76_GHZ} GHz frames/s |"
  echo "|---|---:|---:|---:|---:|---:|---|---|"
  for src in "1000x750 JPEG (replay)|$(a64 BM_JpegDecode/1/)|$(x86 BM_JpegDecode/1/)|1" \
    "12 MP photo, 1/4 DCT decode|$(a64 BM_JpegDecode/4/ a64_12mp)|$(x86 BM_JpegDecode/4/ x86_12mp)|1" \
    "20 MP photo, 1/4 DCT decode (12 MP x 20/12)|$(a64 BM_JpegDecode/4/ a64_12mp)|$(x86 BM_JpegDecode/4/ x86_12mp)|1.6667"; do
    IFS='|' read -r label dec_a dec_x dec_k <<<"$src"
    awk -v l="$label" -v dec="${dec_a:-$dec_x}" -v k="$dec_k" -v sift="$(a64 BM_SiftExtract/1/0/)" \
      -v sift_x="$(x86 BM_SiftExtract/1/0/)" -v idx="$(a64 BM_IndexBuild/)" -v idx_x="$(x86 BM_IndexBuild/)" \
      -v g="$(a64 BM_MatchPair/1/)" -v g_x="$(x86 BM_MatchPair/1/)" -v u="$(a64 BM_MatchPair/0/)" \
      -v u_x="$(x86 BM_MatchPair/0/)" -v e="$EDGES_PER_FRAME" -v o="$OTHER_SHARE" -v f72="$A72_GHZ" -v f76="$A76_GHZ" '
      function fps(simd, br, oth, cores, mem, f, m) {
        return cores * f * 1e9 / ((dec / simd + sift / simd + m / br + other / oth) * (1 + mem))
      }
      BEGIN {
        if (sift == "") { sift = sift_x; idx = idx_x; g = g_x; u = u_x }
        dec *= k
        mg = idx + e * g; mu = idx + e * u
        other = o * (dec + sift + mg)
        # A72: IPC simd 1.2/1.0/0.8, branchy 0.9/0.7/0.5, other 1.0/0.9/0.7; cores 1.8/1.6/1.2; memory 0/5/15 %
        a1 = fps(1.2, 0.9, 1.0, 1.8, 0.00, f72, mg); a2 = fps(1.0, 0.7, 0.9, 1.6, 0.05, f72, mg)
        a3 = fps(0.8, 0.5, 0.7, 1.2, 0.15, f72, mu)
        # A76: IPC simd 2.0/1.8/1.5, branchy 1.6/1.3/1.0, other 1.9/1.6/1.3; cores as A72; memory 0/3/8 %
        b1 = fps(2.0, 1.6, 1.9, 1.8, 0.00, f76, mg); b2 = fps(1.8, 1.3, 1.6, 1.6, 0.03, f76, mg)
        b3 = fps(1.5, 1.0, 1.3, 1.2, 0.08, f76, mu)
        printf "| %s | %.0f M | %.0f M | %.0f M; %.0f M | %.0f M | %.2f G | %.2f / %.2f / %.2f | %.2f / %.2f / %.2f |\n",
          l, dec / 1e6, sift / 1e6, mg / 1e6, mu / 1e6, other / 1e6, (dec + sift + mg + other) / 1e9,
          a1, a2, a3, b1, b2, b3
      }'
  done
} >>"$OUT_DIR/table.md"

# --- aarch64 profile per function (optional) ---------------------------------------------------------------------
# qemu-user maps a position-independent aarch64 program at 0x5500000000 (ELF_ET_DYN_BASE of qemu 7.2's 64-bit
# guests); blocks elsewhere are the shared libraries and the loader, summed as one row (all of them there: the
# program was mapped elsewhere). Names cut at 120 characters may merge template instances.
if [[ ${PROFILE:-0} == 1 && $HAVE_A64 == 1 ]]; then
  echo "aarch64 qemu: SIFT profile per function ..." >&2
  qemu_count "$OUT_DIR/a64_profile.log" ",profile=$OUT_DIR/a64_profile.blocks" "$A64_BIN" \
    --benchmark_filter='BM_SiftExtract/1/0/' --benchmark_min_time=0.000001 >/dev/null
  aarch64-linux-gnu-nm -C --defined-only -n "$A64_BIN" | awk '$2 ~ /^[tTwW]$/' >"$OUT_DIR/a64_profile.symbols"
  python3 - "$OUT_DIR/a64_profile.symbols" "$OUT_DIR/a64_profile.blocks" >"$OUT_DIR/a64_profile.md" <<'PY'
import bisect, collections, sys
base = 0x5500000000
symbols = []
for line in open(sys.argv[1]):
    parts = line.rstrip("\n").split(" ", 2)
    if len(parts) == 3:
        symbols.append((int(parts[0], 16), parts[2]))
symbols.sort()
if not symbols:
    sys.exit("no symbols in the micro-bench (stripped?): no profile per function")
starts = [a for a, _ in symbols]
per_function = collections.Counter()
total = 0
for line in open(sys.argv[2]):
    vaddr, insns, executions = line.split()
    count = int(insns) * int(executions)
    total += count
    offset = int(vaddr, 16) - base
    i = bisect.bisect_right(starts, offset) - 1
    inside = 0 <= offset < starts[-1] + 4096 and i >= 0
    per_function[symbols[i][1][:120] if inside else "(shared libraries, loader)"] += count
print("| function | aarch64 instructions | share |")
print("|---|---:|---:|")
for name, count in per_function.most_common(15):
    print(f"| {name.replace('|', '/')} | {count / 1e6:.1f} M | {100 * count / total:.1f} % |")
print(f"| all | {total / 1e6:.1f} M | 100 % |")
PY
  cat "$OUT_DIR/a64_profile.md" >&2
fi

# --- whole onboard run (optional) ---------------------------------------------------------------------------------
if [[ $WHOLE == 1 || $WHOLE == x86 ]]; then
  echo "whole onboard run, x86-64 callgrind ..." >&2
  rm -rf "$OUT_DIR/whole-x86"
  "${RUN[@]}" valgrind --tool=callgrind --dump-instr=no --callgrind-out-file="$OUT_DIR/whole-x86.cg" \
    "$BUILD/firmware_app/uavmosaic-onboard" --source "replay:$DATA/caliterra_small/images" --out "$OUT_DIR/whole-x86" \
    >"$OUT_DIR/whole-x86.stdout" 2>"$OUT_DIR/whole-x86.stderr"
  wx=$(awk '/^totals:/ { print $2 }' "$OUT_DIR/whole-x86.cg")
  wa=""
  if [[ $WHOLE == 1 && -x $A64_BUILD/firmware_app/uavmosaic-onboard ]] && command -v qemu-aarch64 >/dev/null; then
    echo "whole onboard run, aarch64 qemu ..." >&2
    rm -rf "$OUT_DIR/whole-a64"
    wa=$(qemu_count "$OUT_DIR/whole-a64.log" ',mt=on' "$A64_BUILD/firmware_app/uavmosaic-onboard" \
      --source "replay:$DATA/caliterra_small/images" --out "$OUT_DIR/whole-a64")
  fi
  echo "" >>"$OUT_DIR/table.md"
  echo "whole onboard run (caliterra_small, 20 frames, defaults; OPENCV_FOR_THREADS_NUM=1): x86-64 $wx instructions" \
    "(callgrind), aarch64 ${wa:-n/a} (qemu plugin); sift_bands $(jq .memory.plan.sift_bands "$OUT_DIR/whole-x86/report.json")" \
    >>"$OUT_DIR/table.md"
fi
cat "$OUT_DIR/table.md"
