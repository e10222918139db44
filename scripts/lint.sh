#!/usr/bin/env bash
# Formats (clang-format -i) and lints (clang-tidy, on the compile database of build/ or $UAVM_BUILD_DIR) the
# project's own sources.
# `scripts/lint.sh --check` only reports formatting differences (exit 1 when any).
# `scripts/lint.sh --function-size [--all] [--mark]` only runs clang-tidy's readability-function-size (thresholds in
# .clang-tidy) over core/, hal/, firmware_app/, ground_app/ and tools/, two files at a time: exit 1 when a function
# exceeds them and is not in scripts/function_size_exceptions.txt, or when an exception there no longer exceeds them
# (so the list only shrinks). Without --all only what changed since the commit in scripts/function_size_checked_at
# (a full check passed there): the sources changed since, and those including a changed header; every source when
# that commit is not in the history (a shallow clone), or the thresholds, the exceptions or this script changed.
# Parsing is the step's cost (~4-8 min for every source on 2 cores); the full tier checks every source. --mark (with
# --all) writes HEAD into scripts/function_size_checked_at when the full check passes on a clean tree: commit it.
# `scripts/lint.sh --layers` only checks every #include and CMake dependency between folders against
# scripts/layers.txt (exit 1 on one the table does not allow, or on a folder it does not list).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
BUILD_DIR="${UAVM_BUILD_DIR:-build}"
[[ "$BUILD_DIR" = /* ]] || BUILD_DIR="$ROOT/$BUILD_DIR"
mapfile -t FILES < <(git ls-files '*.cpp' '*.h' | grep -E '^(core|hal|firmware_app|tests|bench|tools|fuzz)/')

# tidy_db DIR [pch]: the build's compile database in DIR for clang-tidy. The precompiled header is g++'s (.gch), which
# clang-tidy refuses to read: without `pch` its -include goes, and each source parses only the headers it includes
# (as in a UAVM_PCH=OFF tree, and twice as fast); with `pch` the header is included as text (-Xclang skips the
# driver's .gch lookup), for a source that only compiles with the PCH's headers.
# g++'s own optimisation flags, which clang refuses (core/features/CMakeLists.txt), go too.
tidy_db() {
  mkdir -p "$1"
  if [ "${2:-}" = pch ]; then
    sed -E 's#-include ([^ "]*cmake_pch\.hxx)#-Xclang -include -Xclang \1#g' "$BUILD_DIR/compile_commands.json"
  else
    sed -E 's#-include [^ "]*cmake_pch\.hxx##g' "$BUILD_DIR/compile_commands.json"
  fi | sed -E 's# -fno-predictive-commoning##g' >"$1/compile_commands.json"
}

# The commit of the last full pass (scripts/function_size_checked_at), when it is in this clone's history.
marked_commit() {
  local base
  base=$(sed -E 's/#.*//' "$ROOT/scripts/function_size_checked_at" 2>/dev/null | tr -d '[:space:]')
  [[ -n $base ]] && git cat-file -e "$base^{commit}" 2>/dev/null && git merge-base --is-ancestor "$base" HEAD &&
    echo "$base"
}

# changed_sources BASE SOURCE...: the files a check since BASE must parse and judge: each changed header and every
# header including one (directly or through others), then "--", then the given sources changed since BASE or
# including one of those headers; "all" when what decides the check changed.
changed_sources() {
  local base=$1 changed
  shift
  changed=$({ git diff --name-only "$base" --; git ls-files --others --exclude-standard; } | sort -u)
  if grep -qxE '\.clang-tidy|scripts/function_size_exceptions\.txt|scripts/lint\.sh' <<<"$changed"; then
    echo all
    return
  fi
  local -A reached=()
  local h headers
  headers=$(grep -E '^(core|hal|firmware_app|ground_app|tools)/.*\.h$' <<<"$changed" || true)
  # Headers including a changed header, until no new one appears.
  while [[ -n $headers ]]; do
    local next=""
    for h in $headers; do
      [[ -n ${reached[$h]+x} ]] && continue
      reached[$h]=1
      next+=$(git grep -l -F "#include \"$h\"" -- '*.h' || true)$'\n'
    done
    headers=$(grep -v '^$' <<<"$next" | sort -u || true)
  done
  printf '%s\n' "${!reached[@]}" --
  # One search for every reached header's #include (the sources that include none are the most).
  local including=""
  if ((${#reached[@]})); then
    including=$(printf '#include "%s"\n' "${!reached[@]}" | git grep -l -F -f - -- "$@" || true)
  fi
  printf '%s\n' "$@" | grep -xF -f <(printf '%s\n' "$changed" "$including" | grep -v '^$') || true
}

function_size() {
  local scope=changed mark=0 arg
  for arg in "$@"; do
    case $arg in
      --all) scope=all ;;
      --mark) mark=1 ;;
      *)
        echo "lint: --function-size takes --all and --mark, not $arg" >&2
        return 2
        ;;
    esac
  done
  if [[ $mark == 1 && $scope != all ]]; then
    echo "lint: --mark needs --all" >&2
    return 2
  fi
  local t0 tmp exceptions="$ROOT/scripts/function_size_exceptions.txt"
  t0=$(date +%s)
  if [ ! -f "$BUILD_DIR/compile_commands.json" ]; then
    echo "lint: no $BUILD_DIR/compile_commands.json (configure the build first, or set UAVM_BUILD_DIR)" >&2
    return 2
  fi
  tmp=$(mktemp -d)
  # shellcheck disable=SC2064  # expand now: tmp is local
  trap "rm -rf '$tmp'" EXIT
  tidy_db "$tmp"
  # Only sources the build compiles (hal/'s optional back ends may be configured out); headers are checked through
  # them, each function reported once.
  mapfile -t SRCS < <(git ls-files '*.cpp' | grep -E '^(core|hal|firmware_app|ground_app|tools)/' |
    while read -r f; do grep -qF "\"file\": \"$ROOT/$f\"" "$tmp/compile_commands.json" && echo "$f"; done)
  local all_sources=${#SRCS[@]} base checked_files
  # The files whose exceptions this run can judge: the sources it parses and, in a changed run, the headers reached.
  if [[ $scope == changed ]] && base=$(marked_commit); then
    mapfile -t CHANGED < <(changed_sources "$base" "${SRCS[@]}")
  else
    CHANGED=(all)
  fi
  if [[ ${CHANGED[0]:-} == all ]]; then
    scope=all
    checked_files=$(printf '%s\n' "${SRCS[@]}")
  else
    local i
    for i in "${!CHANGED[@]}"; do [[ ${CHANGED[$i]} == -- ]] && break; done
    checked_files=$(printf '%s\n' "${CHANGED[@]}" | grep -vx -- '--' || true)
    SRCS=("${CHANGED[@]:i+1}")
  fi
  if [[ ${#SRCS[@]} -eq 0 ]]; then
    echo "lint: function size: no source changed since the last full check ($all_sources sources)"
    return 0
  fi
  tidy_db "$tmp/pch" pch
  export LINT_TMP="$tmp" LINT_ROOT="$ROOT"
  # A source that does not parse without the PCH (a missing #include) is tried again with it, and named.
  # shellcheck disable=SC2016  # the inner bash expands them
  printf '%s\n' "${SRCS[@]}" | xargs -P2 -I{} bash -c '
    tidy() {
      clang-tidy -p "$1" --quiet --checks="-*,readability-function-size" \
        --header-filter="^$LINT_ROOT/(core|hal|firmware_app|ground_app|tools)/" "$LINT_ROOT/$2" >"$3" 2>&1
    }
    out="$LINT_TMP/out.$(echo "$1" | tr / _)"
    tidy "$LINT_TMP" "$1" "$out" && exit 0
    echo "$1" >>"$LINT_TMP/needs_pch"
    tidy "$LINT_TMP/pch" "$1" "$out" || echo "$1" >>"$LINT_TMP/failed"' _ {}
  if [ -s "$tmp/needs_pch" ]; then
    echo "lint: parsed only with the precompiled header's includes (an #include missing?):" \
      "$(sort "$tmp/needs_pch" | tr '\n' ' ')"
  fi
  if [ -s "$tmp/failed" ]; then
    echo "lint: clang-tidy could not parse:" >&2
    while read -r f; do
      echo "  $f" >&2
      grep -E ': error:' "$tmp/out.$(echo "$f" | tr / _)" | head -5 >&2 || true
    done <"$tmp/failed"
    return 1
  fi
  # One line per function over a threshold: "file:function<TAB>file:line<TAB>why".
  cat "$tmp"/out.* | awk -v root="$ROOT/" '
    match($0, /^[^:]+:[0-9]+:[0-9]+: warning: function .* exceeds recommended size/) {
      split($0, p, ":"); file = substr(p[1], length(root) + 1); at = file ":" p[2]
      name = $0; sub(/^[^'\'']*'\''/, "", name); sub(/'\''.*$/, "", name)
      key[at] = file ":" name; next
    }
    /: note: / && (split($0, p, ":") >= 4) {
      at = substr(p[1], length(root) + 1) ":" p[2]
      n = $0; sub(/^.*: note: /, "", n)
      if (!((at, n) in seen)) { seen[at, n] = 1; why[at] = why[at] (why[at] == "" ? "" : "; ") n }
    }
    END { for (at in key) printf "%s\t%s\t%s\n", key[at], at, why[at] }' | sort -u >"$tmp/flagged"
  sed -E 's/#.*//; s/[[:space:]]+$//; s/^[[:space:]]+//; /^$/d' "$exceptions" | sort -u >"$tmp/allowed"
  local over stale
  over=$(cut -f1 "$tmp/flagged" | sort -u | comm -23 - "$tmp/allowed")
  stale=$(cut -f1 "$tmp/flagged" | sort -u | comm -13 - "$tmp/allowed")
  if [[ $scope == changed ]]; then  # an exception in a file this run did not parse cannot be judged
    stale=$(while read -r k; do
      [[ -n $k ]] && grep -qxF "${k%%:*}" <<<"$checked_files" && echo "$k"
    done <<<"$stale" || true)
  fi
  echo "lint: function size: ${#SRCS[@]} of $all_sources sources ($scope), $(wc -l <"$tmp/flagged") function(s)" \
    "over the thresholds, $(wc -l <"$tmp/allowed") exception(s), $(($(date +%s) - t0)) s"
  local status=0
  if [ -n "$over" ]; then
    echo "lint: functions over the size thresholds (.clang-tidy): split them, or list them with a reason in" \
      "scripts/function_size_exceptions.txt" >&2
    while read -r k; do awk -F'\t' -v k="$k" '$1 == k { print "  " $2 " " k " (" $3 ")" }' "$tmp/flagged" >&2; done \
      <<<"$over"
    status=1
  fi
  if [ -n "$stale" ]; then
    echo "lint: exceptions no longer over the thresholds: remove them from scripts/function_size_exceptions.txt" >&2
    sed 's/^/  /' <<<"$stale" >&2
    status=1
  fi
  if [[ $mark == 1 && $status == 0 ]]; then
    if [[ -n $(git status --porcelain -- core hal firmware_app ground_app tools .clang-tidy scripts) ]]; then
      echo "lint: not marked: the tree has uncommitted changes (the mark names a commit)" >&2
      return 1
    fi
    sed -i -E "s/^[0-9a-f]{40}\$/$(git rev-parse HEAD)/" "$ROOT/scripts/function_size_checked_at"
    echo "lint: function size: every source checked at $(git rev-parse --short HEAD) (commit scripts/function_size_checked_at)"
  fi
  return "$status"
}

# folder_of PATH: sets FOLDER to PATH's layer folder (core/X, hal/X, or the top folder). A variable, not an echo in a
# command substitution: the check runs it for every include line, and the forks were the whole step's 20 s.
folder_of() {
  local rest
  case $1 in
    core/* | hal/*)
      rest=${1#*/}
      FOLDER=${1%%/*}/${rest%%/*}
      ;;
    *) FOLDER=${1%%/*} ;;
  esac
}

layers() {
  local table="$ROOT/scripts/layers.txt" status=0 line folder file inc dst target cm
  declare -A allowed
  while IFS= read -r line; do
    line=${line%%#*}
    [[ -z ${line// /} ]] && continue
    allowed[${line%%:*}]=" ${line#*:} "
  done <"$table"
  # use FOLDER DST WHERE: fails unless the table lets FOLDER use DST.
  use() {
    [[ $1 == "$2" ]] && return 0
    if [[ -z ${allowed[$1]+x} ]]; then
      echo "layers: $1 is not in scripts/layers.txt ($3)" >&2
      return 1
    fi
    [[ ${allowed[$1]} == *" $2 "* ]] && return 0
    echo "layers: $1 uses $2 ($3), which scripts/layers.txt does not allow" >&2
    return 1
  }
  while IFS=: read -r file _ inc; do
    inc=${inc#*\"}
    inc=${inc%%\"*}
    folder_of "${inc%/*}"
    dst=$FOLDER
    folder_of "$file"
    use "$FOLDER" "$dst" "$file: #include \"$inc\"" || status=1
  done < <(git grep --untracked -n -E '^#include "(core|hal|firmware_app|ground_app|tools)/' -- core hal firmware_app ground_app tools)
  while IFS= read -r cm; do
    folder=$(dirname "$cm")
    for target in $(grep -oE 'uavm_(core|hal)_[a-z0-9_]+' "$cm" | sort -u); do
      dst=$(echo "$target" | sed -E 's#^uavm_(core|hal)_#\1/#')
      [[ -d $dst ]] || continue # a target of another name (uavm_core_eval_* helpers are core/eval's)
      use "$folder" "$dst" "$cm: $target" || status=1
    done
  done < <(git ls-files 'core/*/CMakeLists.txt' 'hal/*/CMakeLists.txt' firmware_app/CMakeLists.txt ground_app/CMakeLists.txt tools/CMakeLists.txt)
  [[ $status == 0 ]] && echo "layers: every include and link between folders is in scripts/layers.txt"
  return "$status"
}

case "${1:-}" in
  --layers)
    layers
    exit $?
    ;;
  --check)
    clang-format --dry-run --Werror "${FILES[@]}"
    exit $?
    ;;
  --function-size)
    shift
    function_size "$@"
    exit $?
    ;;
esac
clang-format -i "${FILES[@]}"
if [ -f "$BUILD_DIR/compile_commands.json" ]; then
  TIDY_DB=$(mktemp -d)
  trap 'rm -rf "$TIDY_DB"' EXIT
  tidy_db "$TIDY_DB"
  mapfile -t SRCS < <(printf '%s\n' "${FILES[@]}" | grep -E '^(core|hal|firmware_app)/.*\.cpp$')
  clang-tidy -p "$TIDY_DB" --quiet "${SRCS[@]}" 2>/dev/null | grep -E "warning|error" || echo "clang-tidy: clean"
fi
