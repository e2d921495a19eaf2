#!/bin/sh
# solve_grid.sh BIOTGRID GRID_CONFIG SCENE WORKDIR NO_AGENTS_LEFT
# The README's `biotgrid grid up && biotgrid solve SCENE --grid` on the
# default grid config (a broker and its agents; ephemeral loopback ports,
# the state in WORKDIR): solve buys its services on the broker's market.
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
# `grid down` then, and no process of the grid is left.
set -u
bin=$1 config=$2 scene=$3 work=$4 no_left=$5
rm -rf "$work"
mkdir -p "$work"
state="$work/grid"
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
trap '"$bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM
BIOTGRID_GRID_DIR=$state
export BIOTGRID_GRID_DIR

# same METHOD GRID_REPORT LOCAL_REPORT: equal energy (1e-10 relative) and iterations.
same() {
    jq -e --arg m "$1" --slurpfile g "$2" --slurpfile l "$3" '
        ($g[0].runs[] | select(.method == $m)) as $a | ($l[0].runs[] | select(.method == $m)) as $b |
        (($a.energy - $b.energy) | fabs) <= 1e-10 * ($b.energy | fabs) and
        $a.iterations == $b.iterations and $a.converged and $b.converged' >/dev/null 2>&1
}

"$bin" solve "$scene" --compare newton,local-global --quiet --out "$work/local" \
    >"$work/local.txt" 2>&1 || fail "the in-process solve failed: $(cat "$work/local.txt")"

"$bin" grid up "$config" --state "$state" --broker-port 0 --broker-endpoint 'tcp://127.0.0.1:*' \
    >"$work/up.txt" 2>&1 || fail "grid up: $(cat "$work/up.txt")"

# 1. One method, the scene's; events on stderr (not a terminal: plain lines).
timeout 200 "$bin" solve "$scene" --grid --out "$work/one" >"$work/one.out" 2>"$work/one.err"
s=$?
cat "$work/one.err" "$work/one.out"
[ $s -eq 0 ] || fail "solve --grid exited $s"
grep -Eq "^job j[0-9a-f]{16}: contract: rotation-fit from agent rotfit-[12], price " "$work/one.err" ||
    fail "solve --grid does not show the job's contracts"
grep -Eq "^newton: converged after [0-9]+ iterations" "$work/one.err" || fail "no outcome line"
grep -Eq "^newton +2 +[0-9.]+ +[0-9.e+-]+ +[0-9.e+-]+ +[0-9.e+-]+$" "$work/one.out" ||
    fail "no error-against-run-time table"
grep -Eq "^  newton +job j[0-9a-f]{16}: 3 contracts, spent [0-9.e+]+ of budget 1000" "$work/one.out" ||
    fail "the money the job spent is not shown"
for f in report.json error-vs-time.svg result.vtu result.mesh; do
    [ -s "$work/one/$f" ] || fail "solve --grid did not write $f"
done
[ "$(jq -r .market.mechanism "$work/one/report.json" 2>/dev/null)" = central ] ||
    fail "the job was not bought under the central mechanism"
same newton "$work/one/report.json" "$work/local/report.json" ||
    fail "newton on the grid: energy $(jq .runs[0].energy "$work/one/report.json") or iterations differ from in process"

# 2. Two methods compared, under posted with a budget.
timeout 300 "$bin" solve "$scene" --grid --compare newton,local-global --mechanism posted \
    --budget 50 --quiet --out "$work/cmp" >"$work/cmp.out" 2>&1
s=$?
cat "$work/cmp.out"
[ $s -eq 0 ] || fail "solve --grid --compare exited $s"
for m in newton local-global; do
    [ -s "$work/cmp/$m/report.json" ] || fail "no $m/report.json"
    [ "$(jq -r .market.mechanism "$work/cmp/$m/report.json" 2>/dev/null)" = posted ] ||
        fail "$m: not bought under posted"
    same $m "$work/cmp/$m/report.json" "$work/local/report.json" ||
        fail "$m on the grid: energy or iterations differ from in process"
    grep -Eq "^  $m +job j[0-9a-f]{16}: 3 contracts, spent [0-9.e+]+ of budget 50" "$work/cmp.out" ||
        fail "$m: the money its job spent is not shown"
done
[ "$(grep -c '<polyline' "$work/cmp/error-vs-time.svg" 2>/dev/null)" -ge 2 ] ||
    fail "no combined plot with both methods"
grep -Eq "^1e-08 +[0-9.]+ s \\(it [0-9]+\\) +[0-9.]+ s \\(it [0-9]+\\) +(newton|local-global)$" "$work/cmp.out" ||
    fail "no time-to-accuracy table"

"$bin" grid down --state "$state" >"$work/down.txt" 2>&1 || fail "grid down: $(cat "$work/down.txt")"
sh "$no_left" "$state" || fail "a process of the grid is left"

# 3. A grid without a broker has no market to buy on.
mkdir -p "$work/plain"
printf '{"name": "plain", "agents": []}\n' >"$work/plain/grid.json"
"$bin" solve "$scene" --grid --grid-state "$work/plain" --mechanism posted >"$work/plain.txt" 2>&1
s=$?
[ $s -eq 2 ] && grep -q "has no broker" "$work/plain.txt" ||
    fail "--mechanism on a grid without a broker: exit $s, $(cat "$work/plain.txt")"

[ $fails -eq 0 ] && echo "solve_grid: ok"
exit $fails
