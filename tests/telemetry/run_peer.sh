#!/usr/bin/env bash
# run_peer.sh SCRIPT.mjs ARGS...: runs a test peer script (tests/telemetry/*.mjs) with node-mavlink, the independent
# MAVLink implementation the decoder is tested against, installed as package-lock.json pins it into a cache outside
# the clone (UAVM_CACHE_DIR, default ~/.cache/uavmosaic: a read-only clone works). Needs node and npm (scripts/setup.sh)
# and, the first time, the npm registry.
#   run_peer.sh --install: installs only, and prints the node_modules folder.
#   UAVM_PEER_MODULES=DIR run_peer.sh SCRIPT.mjs ARGS...: uses that installed node_modules, read-only (the camera VM
#   sees the host's cache through a read-only mount), without the cache.
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
SCRIPT=$1
shift
if [ -n "${UAVM_PEER_MODULES:-}" ]; then
  RUN_DIR=$(mktemp -d)
  trap 'rm -rf "$RUN_DIR"' EXIT
  ln -s "$UAVM_PEER_MODULES" "$RUN_DIR/node_modules"
  cp "$SCRIPT" "$RUN_DIR/peer.mjs"
  node "$RUN_DIR/peer.mjs" "$@"
  exit
fi
LOCK_ID=$(sha256sum "$HERE/package-lock.json" | cut -c1-12)
CACHE=${UAVM_CACHE_DIR:-$HOME/.cache/uavmosaic}/npm-telemetry-$LOCK_ID
mkdir -p "$CACHE"
(
  flock 9  # tests run in parallel: one installs, the others wait
  if [ ! -f "$CACHE/node_modules/node-mavlink/package.json" ]; then
    cp "$HERE/package.json" "$HERE/package-lock.json" "$CACHE/"
    (cd "$CACHE" && npm ci --no-audit --no-fund --loglevel=error >&2) ||
      { echo "run_peer: npm ci failed (is the npm registry reachable?)" >&2; exit 1; }
  fi
) 9>"$CACHE/.lock"
if [ "$SCRIPT" = --install ]; then
  echo "$CACHE/node_modules"
  exit 0
fi
# ES modules resolve packages from the script's own folder: run a copy placed beside node_modules.
RUN=$(mktemp "$CACHE/run.XXXXXX.mjs")
trap 'rm -f "$RUN"' EXIT
cp "$SCRIPT" "$RUN"
node "$RUN" "$@"
