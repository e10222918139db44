#!/usr/bin/env bash
# ci_times.sh [LOG_DIR]: the time table of a test run (scripts/test.sh or scripts/test_full.sh, which call it at the
# end; LOG_DIR defaults to ci-logs/). Prints each step's wall time against its recorded time (scripts/ci_times.tsv),
# then the ten slowest tests of the run's ctest logs. Exit 1 when a step took more than 1.5x its recorded time
# (and at least 30 s more, so that a step of seconds does not fail on noise), so that a slow regression is seen long
# before CI's 90-minute limit; UAVM_CI_GUARD=0 reports without failing.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
LOG_DIR="${1:-$ROOT/ci-logs}"
RECORDED="$ROOT/scripts/ci_times.tsv"
[ -f "$LOG_DIR/steps.tsv" ] || { echo "ci_times: no $LOG_DIR/steps.tsv (run scripts/test.sh first)" >&2; exit 2; }

awk -F'\t' -v guard="${UAVM_CI_GUARD:-1}" '
  FNR == NR { if ($0 !~ /^#/ && NF >= 2) recorded[$1] = $2; next }
  {
    name = $1; secs = $2; status = $3; total += secs
    rec = (name in recorded) ? recorded[name] : ""
    limit = (rec == "") ? 0 : (rec * 1.5 > rec + 30 ? rec * 1.5 : rec + 30)
    verdict = (status != 0) ? "FAILED" : "ok"
    if (rec != "" && secs > limit) { verdict = "SLOW (limit " int(limit) " s)"; slow++ }
    rows[++n] = sprintf("| %-20s | %7d | %8s | %5s | %-22s |", name, secs, rec == "" ? "-" : rec,
                        rec == "" || rec == 0 ? "-" : sprintf("%.2f", secs / rec), verdict)
  }
  END {
    print ""
    print "| step                 |  wall s | recorded | ratio | verdict                |"
    print "|----------------------|---------|----------|-------|------------------------|"
    for (i = 1; i <= n; i++) print rows[i]
    printf "| %-20s | %7d |          |       |                        |\n", "total", total
    printf "(%d min %02d s)\n", total / 60, total % 60
    if (slow > 0) {
      print ""
      print "ci_times: " slow " step(s) took more than 1.5x their recorded time (scripts/ci_times.tsv): find the cause" \
            " before CI reaches its 90-minute limit, or record the new time with the reason."
      exit guard == "0" ? 0 : 1
    }
  }' "$RECORDED" "$LOG_DIR/steps.tsv" || status=$?

# The ten slowest tests over the run's ctest logs ("  3/199 Test  #77: Name ....   Passed  120.73 sec").
logs=("$LOG_DIR"/ctest-*.log)
if [ -e "${logs[0]}" ]; then
  echo
  echo "Ten slowest tests:"
  for f in "${logs[@]}"; do
    suite=$(basename "$f" .log)
    suite=${suite#ctest-}
    sed -nE 's/^ *[0-9]+\/[0-9]+ Test +#[0-9]+: ([^ ]+) \.+.* ([0-9.]+) sec$/\2\t\1/p' "$f" |
      awk -F'\t' -v s="$suite" '{ printf "%10.1f s  %-10s %s\n", $1, s, $2 }'
  done | sort -rn | awk 'NR <= 10'  # not head: it exits early, and sort's SIGPIPE (141) failed a green run under pipefail
fi
exit "${status:-0}"
