#!/bin/sh
# solve_grid.sh BIOTGRID GRID_CONFIG SCENE WORKDIR SOURCE_DIR
# The README's `biotgrid grid up && biotgrid solve SCENE --grid` on the
# default grid config (a broker and its agents; ephemeral loopback ports,
# the state in WORKDIR/grid): solve buys its services on the broker's market.
#   1. one method: exit 0, the job's events shown (its contracts), its
#      result files in --out as solve writes them, the error-against-run-
#      time table and the money it spent; its energy equals an in-process
#      `solve` of the same scene to 1e-10 relative, with the same iteration
#      count (the agents sum partial energies in partition order, a
#      round-off difference of about 1e-15; 1e-10 leaves room for that and
#      still catches another minimum; a different count, another path);
#   2. --compare newton,local-global under posted with a budget: each
#      method's files in --out/<method>/, the combined plot at the top, the
#      time-to-accuracy table with both methods, each job's money, and each
#      method's energy equal to its in-process run's as above;
#   3. --mechanism on a grid without a broker is refused (exit 2).
# `grid down` then, and no process of the grid is left (broker_lib.sh).
set -u
bin=$1 config=$2 scene=$3 work=$4 src=$5
. "$src/tests/broker/broker_lib.sh"
grid_test_begin "$bin" "$work"
BIOTGRID_GRID_DIR=$state
export BIOTGRID_GRID_DIR

# same METHOD GRID_REPORT LOCAL_REPORT: equal energy (1e-10 relative) and iterations.
same() {
    jq -e --arg m "$1" --slurpfile g "$2" --slurpfile l "$3" '
        ($g[0].runs[] | select(.method == $m)) as $a | ($l[0].runs[] | select(.method == $m)) as $b |
        (($a.energy - $b.energy) | fabs) <= 1e-10 * ($b.energy | fabs) and
        $a.iterations == $b.iterations and $a.converged and $b.converged' >/dev/null 2>&1
}
# has FILE PATTERN MESSAGE: FILE has a line matching the extended regular expression.
has() { grep -Eq -- "$2" "$1"; check $? "$3"; }

"$bin" solve "$scene" --compare newton,local-global --quiet --out "$work/local" \
    >"$work/local.txt" 2>&1
check $? "the in-process solve"
"$bin" grid up "$config" --state "$state" --broker-port 0 --broker-endpoint 'tcp://127.0.0.1:*' \
    >"$work/up.txt" 2>&1
check $? "grid up"

# 1. One method, the scene's; events on stderr (not a terminal: plain lines).
timeout 200 "$bin" solve "$scene" --grid --out "$work/one" >"$work/one.out" 2>"$work/one.err"
check $? "solve --grid"
cat "$work/one.err" "$work/one.out"
has "$work/one.err" "^job j[0-9a-f]{16}: contract: rotation-fit from agent rotfit-[12], price " \
    "the job's contracts shown"
has "$work/one.err" "^newton: converged after [0-9]+ iterations" "the run's outcome line"
has "$work/one.out" "^newton +2 +[0-9.]+ +[0-9.e+-]+ +[0-9.e+-]+ +[0-9.e+-]+$" \
    "the error-against-run-time table"
has "$work/one.out" "^  newton +job j[0-9a-f]{16}: 3 contracts, spent [0-9.e+]+ of budget 1000" \
    "the money the job spent"
for f in report.json error-vs-time.svg result.vtu result.mesh; do
    [ -s "$work/one/$f" ]; check $? "$f written into --out"
done
[ "$(jq -r .market.mechanism "$work/one/report.json" 2>/dev/null)" = central ]
check $? "bought under the central mechanism"
same newton "$work/one/report.json" "$work/local/report.json"
check $? "newton's energy and iterations on the grid equal the in-process solve's"

# 2. Two methods compared, under posted with a budget.
timeout 300 "$bin" solve "$scene" --grid --compare newton,local-global --mechanism posted \
    --budget 50 --quiet --out "$work/cmp" >"$work/cmp.out" 2>&1
check $? "solve --grid --compare"
cat "$work/cmp.out"
for m in newton local-global; do
    [ "$(jq -r .market.mechanism "$work/cmp/$m/report.json" 2>/dev/null)" = posted ]
    check $? "$m: its files in --out/$m, bought under posted"
    same $m "$work/cmp/$m/report.json" "$work/local/report.json"
    check $? "$m: energy and iterations on the grid equal the in-process solve's"
    has "$work/cmp.out" "^  $m +job j[0-9a-f]{16}: 3 contracts, spent [0-9.e+]+ of budget 50" \
        "$m: the money its job spent"
done
[ "$(grep -c '<polyline' "$work/cmp/error-vs-time.svg" 2>/dev/null)" -ge 2 ]
check $? "the combined plot has both methods"
has "$work/cmp.out" "^1e-08 +[0-9.]+ s \\(it [0-9]+\\) +[0-9.]+ s \\(it [0-9]+\\) +(newton|local-global)$" \
    "the time-to-accuracy table"

grid_test_end "$src/tests/agents"

# 3. A grid without a broker has no market to buy on.
mkdir -p "$work/plain"
printf '{"name": "plain", "agents": []}\n' >"$work/plain/grid.json"
"$bin" solve "$scene" --grid --grid-state "$work/plain" --mechanism posted >"$work/plain.txt" 2>&1
[ $? -eq 2 ] && grep -q "has no broker" "$work/plain.txt"
check $? "--mechanism on a grid without a broker is refused: $(cat "$work/plain.txt")"
exit $fail
