#!/usr/bin/env bash
# Configures and builds into build/ (or $UAVM_BUILD_DIR). Extra arguments go to the CMake configure step.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_BUILD_DIR:-$ROOT/build}"
bash "$ROOT/scripts/setup.sh"
GEN=()
command -v ninja >/dev/null && GEN=(-G Ninja)
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S "$ROOT" -B "$BUILD_DIR" "${GEN[@]}" -DCMAKE_BUILD_TYPE=Release "$@"
fi
cmake --build "$BUILD_DIR" -j "$(nproc)"
