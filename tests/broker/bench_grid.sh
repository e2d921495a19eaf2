#!/bin/sh
# bench_grid.sh BIOTGRID SCENE [WORKDIR] [MECHANISM] [ROUNDS]
# A scene through a local grid (grid up: the broker and 4 agents on
# ephemeral loopback ports; the agents sell on the broker's live market),
# end to end as a user sees it — `biotgrid submit SCENE --out DIR`, from
# the command's start to the result files on disk — against `biotgrid
# solve SCENE` in process, alternated ROUNDS times (default 2) in the same
# run so that drift in the machine's load hits both alike. Prints the
# load, each pair's wall times and ratio, the median ratio, and where the
# grid job's time went: the allocation (buying the plan) and the method's
# run as the job's report accounts them, and the rest (upload,
# validation, preparation and the reference solve, set-up on the agents,
# result download). The
# energies of the two must agree to 1e-10 relative. MECHANISM: posted
# (default), central or catallactic. Run by hand; prints figures, asserts
# no speed. Exit 0, or 1 when a run failed or the energies differ.
set -u
bin=$1 scene=$2 work=${3:-/tmp/bench-grid} mech=${4:-posted} rounds=${5:-2}
here=$(cd "$(dirname "$0")" && pwd)
command -v jq >/dev/null || { echo "bench_grid.sh: needs jq" >&2; exit 1; }
rm -rf "$work"
mkdir -p "$work"
state="$work/grid"
trap '"$bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM
now() { date +%s.%N; }
echo "load before: $(uptime)"
"$bin" grid up "$here/../../configs/grids/local.json" --state "$state" --broker-port 0 \
  --broker-endpoint 'tcp://127.0.0.1:*' >/dev/null || exit 1
failed=0 ratios=""
r=1
while [ "$r" -le "$rounds" ]; do
    t0=$(now)
    "$bin" solve "$scene" --quiet --out "$work/local-$r" >/dev/null 2>&1 || failed=1
    t1=$(now)
    BIOTGRID_GRID_DIR=$state "$bin" submit "$scene" --mechanism "$mech" --budget 100 \
        --out "$work/grid-$r" >"$work/submit-$r.txt" 2>&1 || failed=1
    t2=$(now)
    [ $failed -eq 0 ] || { cat "$work/submit-$r.txt" >&2; break; }
    ratio=$(awk -v a="$t0" -v b="$t1" -v c="$t2" 'BEGIN { printf "%.3f", (c - b) / (b - a) }')
    ratios="$ratios $ratio"
    g=$work/grid-$r/report.json l=$work/local-$r/report.json
    awk -v a="$t0" -v b="$t1" -v c="$t2" -v r="$r" 'BEGIN {
      printf "round %d: solve %.2f s, grid job (submit -> result files) %.2f s, ratio %.2f\n",
        r, b - a, c - b, (c - b) / (b - a) }'
    # Where the grid job's time went, from its report: the run as the
    # coordinator timed it, the allocation as the market section gives it.
    jq -r --arg total "$(awk -v b="$t1" -v c="$t2" 'BEGIN { print c - b }')" '
      (.market.allocation_latency_seconds // 0) as $alloc
      | ([.runs[].wall_seconds] | add) as $runs
      | "  grid: allocation \($alloc * 1000 | round / 1000) s, run \($runs * 1000 | round / 1000) s, the rest \(($total | tonumber) - $alloc - $runs | . * 1000 | round / 1000) s (upload, validation, preparation, the reference solve if the scene has one, set-up on the agents, download); \(.market.mechanism // "no market"), \(.market.contracts | length) contracts, spent \(.market.spent)"' "$g"
    jq -r '"  solve: run \([.runs[].wall_seconds] | add | . * 1000 | round / 1000) s (the rest: reading, preparation, the reference solve if any, writing)"' "$l"
    jq -n --slurpfile a "$g" --slurpfile b "$l" \
      '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' |
      grep -q true || { echo "bench_grid.sh: the energies differ" >&2; failed=1; }
    r=$((r + 1))
done
"$bin" grid down --state "$state" >/dev/null
echo "load after: $(uptime)"
[ -n "$ratios" ] && echo "$ratios" | tr ' ' '\n' | sed '/^$/d' | sort -n |
    awk '{ v[NR] = $1 } END { m = NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2;
                              printf "median ratio grid / solve: %.2f over %d rounds\n", m, NR }'
exit $failed
