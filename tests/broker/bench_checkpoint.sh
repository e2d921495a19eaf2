#!/bin/sh
# bench_checkpoint.sh BIOTGRID SCENE [WORKDIR] [ROUNDS]
# What keeping checkpoints costs a job that loses nothing (issue 27): two
# local grids from configs/grids/local.json, one whose broker recovers lost
# agents (agent_recovery, the default: the coordinator keeps a copy of
# every matrix it has factored and of the time loop's last steps) and one
# that does not (a loss fails the job, nothing is kept), both up at once on
# ephemeral loopback ports. SCENE is submitted to each in turn ROUNDS
# times (default 3), alternated so that drift in the machine's load hits
# both alike. Prints the load, each round's method run (the report's
# runs[].wall_seconds) and end-to-end time (submit -> result files) with
# and without, and the median ratios. The energies must agree to 1e-10
# relative. Run by hand (tests/bench/figures.sh has it as a part); prints
# figures, asserts no speed. Exit 0, or 1 when a run failed or the
# energies differ.
set -u
bin=$1 scene=$2 work=${3:-/tmp/bench-checkpoint} rounds=${4:-3}
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
command -v jq >/dev/null || { echo "bench_checkpoint.sh: needs jq" >&2; exit 1; }
rm -rf "$work"
mkdir -p "$work"
down() {
  for g in with without; do "$bin" grid down --state "$work/$g/grid" >/dev/null 2>&1; done
}
trap 'down; exit 1' INT TERM
trap down EXIT
echo "load before: $(uptime)"
for g in with without; do
  mkdir -p "$work/$g"
  rec=true
  [ "$g" = without ] && rec=false
  jq --argjson r "$rec" '.broker.agent_recovery = $r' "$here/../../configs/grids/local.json" \
    >"$work/$g/grid.json"
  "$bin" grid up "$work/$g/grid.json" --state "$work/$g/grid" --broker-port 0 \
    --broker-endpoint 'tcp://127.0.0.1:*' >/dev/null || exit 1
done
failed=0
: >"$work/rounds"
r=1
while [ "$r" -le "$rounds" ] && [ $failed -eq 0 ]; do
  for g in with without; do
    t0=$(now)
    BIOTGRID_GRID_DIR=$work/$g/grid "$bin" submit "$scene" --mechanism posted --budget 100 \
      --out "$work/$g/out-$r" >"$work/$g/submit-$r.txt" 2>&1 || { failed=1; cat "$work/$g/submit-$r.txt" >&2; }
    t1=$(now)
    [ $failed -eq 0 ] || break
    run=$(jq '[.runs[].wall_seconds] | add' "$work/$g/out-$r/report.json")
    echo "$r $g $run $(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }')" >>"$work/rounds"
  done
  [ $failed -eq 0 ] || break
  jq -n --slurpfile a "$work/with/out-$r/report.json" --slurpfile b "$work/without/out-$r/report.json" \
    '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' |
    grep -q true || { echo "bench_checkpoint.sh: the energies differ" >&2; failed=1; }
  r=$((r + 1))
done
echo "load after: $(uptime)"
awk '
  { run[$2, $1] = $3; total[$2, $1] = $4; n = $1 > n ? $1 : n }
  function median(v, k,   i, j, t) {
    for (i = 1; i <= k; i++) for (j = i + 1; j <= k; j++) if (v[j] < v[i]) { t = v[i]; v[i] = v[j]; v[j] = t }
    return k % 2 ? v[(k + 1) / 2] : (v[k / 2] + v[k / 2 + 1]) / 2
  }
  END {
    for (i = 1; i <= n; i++) {
      if (!((("with", i) in run) && (("without", i) in run))) continue
      k++
      printf "round %d: run %.3f s with checkpoints, %.3f s without (%.3f); submit -> result %.2f s, %.2f s (%.3f)\n",
        i, run["with", i], run["without", i], run["with", i] / run["without", i],
        total["with", i], total["without", i], total["with", i] / total["without", i]
      rr[k] = run["with", i] / run["without", i]; tr[k] = total["with", i] / total["without", i]
    }
    if (k) printf "median ratio with / without checkpoints: run %.3f, end to end %.3f over %d rounds\n",
      median(rr, k), median(tr, k), k
  }' "$work/rounds"
exit $failed
