#!/bin/sh
# solve_grid_inner.sh BIOTGRID GRID_CONFIG SCENE WORKDIR SOURCE_DIR
# A dynamic scene's quasi-newton inner solve bought on a grid's market:
# `biotgrid solve SCENE --inner quasi-newton` in process and with --grid
# (the option travels in the job's solver settings as solver.inner). The
# grid's job must say which inner solve ran (its report's "inner" and the
# console's "quasi-newton iterations") and give the in-process energy to
# 1e-10 relative with the same iteration count: the agents sum partial
# energies in partition order, a round-off difference that moves neither
# this short run's counts nor its energy beyond 1e-10 (agents.same
# checks the same scene on 1-3 rotation-fit agents). `grid down` then,
# and no process of the grid is left (broker_lib.sh).
set -u
bin=$1 config=$2 scene=$3 work=$4 src=$5
. "$src/tests/broker/broker_lib.sh"
grid_test_begin "$bin" "$work"
BIOTGRID_GRID_DIR=$state
export BIOTGRID_GRID_DIR

"$bin" solve "$scene" --inner quasi-newton --quiet --out "$work/local" >"$work/local.txt" 2>&1
check $? "the in-process solve"
"$bin" grid up "$config" --state "$state" --broker-port 0 --broker-endpoint 'tcp://127.0.0.1:*' \
    >"$work/up.txt" 2>&1
check $? "grid up"
timeout 200 "$bin" solve "$scene" --grid --inner quasi-newton --quiet --out "$work/grid" \
    >"$work/grid.out" 2>"$work/grid.err"
check $? "solve --grid --inner quasi-newton"
cat "$work/grid.err" "$work/grid.out"
grep -Eq "^variational: completed, [0-9]+ steps, [0-9]+ quasi-newton iterations" "$work/grid.err"
check $? "the run's outcome line counts quasi-newton iterations"
for r in local grid; do
    [ "$(jq -r '.runs[0].inner' "$work/$r/report.json" 2>/dev/null)" = quasi-newton ]
    check $? "$r: the report names the inner solve"
done
jq -e --slurpfile g "$work/grid/report.json" --slurpfile l "$work/local/report.json" -n '
    $g[0].runs[0] as $a | $l[0].runs[0] as $b |
    (($a.energy - $b.energy) | fabs) <= 1e-10 * ($b.energy | fabs) and
    $a.iterations == $b.iterations and $a.converged and $b.converged' >/dev/null 2>&1
check $? "energy and iterations on the grid equal the in-process solve's"
grid_test_end "$src/tests/agents"
exit $fail
