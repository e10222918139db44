#!/usr/bin/env bash
# Set-up-free test run: installs what is missing, builds, then runs the whole CTest suite.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${UAVM_BUILD_DIR:-$ROOT/build}"
bash "$ROOT/scripts/build.sh"
cd "$BUILD_DIR"
ctest --output-on-failure -j "$(nproc)" --timeout 900
