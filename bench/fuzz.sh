#!/usr/bin/env bash
# The long fuzzing run: every libFuzzer target for RUNS executions (default 10^6), then each corpus is minimised
# (libFuzzer -merge) back into fuzz/corpus/<target>/, ready to commit. Usage: bench/fuzz.sh [RUNS]
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
exec bash "$ROOT/scripts/fuzz.sh" --runs "${1:-1000000}" --minimize
