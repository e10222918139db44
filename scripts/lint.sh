#!/usr/bin/env bash
# Formats (clang-format -i) and lints (clang-tidy, on the compile database of build/) the project's own sources.
# `scripts/lint.sh --check` only reports formatting differences (exit 1 when any).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
mapfile -t FILES < <(git ls-files '*.cpp' '*.h' | grep -E '^(core|hal|firmware_app|tests|bench|tools|fuzz)/')
if [ "${1:-}" = "--check" ]; then
  clang-format --dry-run --Werror "${FILES[@]}"
  exit 0
fi
clang-format -i "${FILES[@]}"
if [ -f build/compile_commands.json ]; then
  mapfile -t SRCS < <(printf '%s\n' "${FILES[@]}" | grep -E '^(core|hal|firmware_app)/.*\.cpp$')
  clang-tidy -p build --quiet "${SRCS[@]}" 2>/dev/null | grep -E "warning|error" || echo "clang-tidy: clean"
fi
