#!/bin/sh
# solve_cli.sh BIOTGRID RUNDIR SCENE OUTDIR DYNAMIC-SCENE
# `biotgrid solve --agents` on RUNDIR's agents (a1, a2 rotation-fit, sv
# sparse-solve, ig integration-step, their services given so no heartbeat
# is needed): exit 0, a per-agent line with calls for each service used,
# the integration-step agent not contacted (console and report.json), and
# `--grid-state` reading a grid state file naming the same agents. Then
# DYNAMIC-SCENE across the same agents: the integration-step agent's line
# shows calls, compute seconds and bytes, and the run ends with the steps,
# Newton iterations and energy drift of the in-process run.
set -u
bin=$1 dir=$2 scene=$3 out=$4 dynamic=$5
ep() { cut -d' ' -f1 "$dir/$1.ready"; }
agents="rotfit=$(ep a1),rotfit=$(ep a2),solve=$(ep sv),integ=$(ep ig)"
fail() { echo "solve_cli: $*" >&2; exit 1; }
log=$("$bin" solve "$scene" --compare newton,local-global --quiet --agents "$agents" \
      --out "$out/agents" 2>&1) || { printf '%s\n' "$log"; fail "solve --agents failed"; }
printf '%s\n' "$log"
for a in a1 a2; do
  printf '%s\n' "$log" | grep -Eq "rotation-fit +$(ep $a): [1-9][0-9]* calls, compute" ||
    fail "no rotation-fit line with calls for $a"
done
printf '%s\n' "$log" | grep -Eq "sparse-solve +$(ep sv): [1-9][0-9]* calls" ||
  fail "no sparse-solve line with calls"
printf '%s\n' "$log" | grep -Eq "integration-step $(ep ig): not contacted" ||
  fail "the integration-step agent is not reported as not contacted"
grep -q '"agents"' "$out/agents/report.json" || fail "report.json has no agents section"
grep -q '"contacted":[[:space:]]*false' "$out/agents/report.json" ||
  fail "report.json does not show the agent left out"
# The grid state file form (what `grid up` writes).
mkdir -p "$out/grid"
cat >"$out/grid/grid.json" <<JSON
{"name": "test", "agents": [
 {"name": "a1", "endpoint": "$(ep a1)", "pid": 1, "services": "rotfit", "slots": 4},
 {"name": "sv", "endpoint": "$(ep sv)", "pid": 1, "services": "solve", "slots": 4},
 {"name": "ig", "endpoint": "$(ep ig)", "pid": 1, "services": "integ", "slots": 4}]}
JSON
log=$("$bin" solve "$scene" --method newton --quiet --grid --grid-state "$out/grid" \
      --out "$out/grid-out" 2>&1) || { printf '%s\n' "$log"; fail "solve --grid failed"; }
printf '%s\n' "$log" | grep -Eq "rotation-fit +$(ep a1): [1-9][0-9]* calls" ||
  fail "--grid: no rotation-fit line"
printf '%s\n' "$log" | grep -Eq "integration-step $(ep ig): not contacted" ||
  fail "--grid: the integration-step agent was contacted"
# A dynamic scene: the time loop's state on the integration-step agent.
log=$("$bin" solve "$dynamic" --quiet --agents "$agents" --out "$out/dyn-agents" 2>&1) ||
  { printf '%s\n' "$log"; fail "dynamic solve --agents failed"; }
printf '%s\n' "$log"
printf '%s\n' "$log" |
  grep -Eq "integration-step $(ep ig): [1-9][0-9]* calls, compute [0-9.]+ s, sent [1-9][0-9]* B, received [1-9][0-9]* B" ||
  fail "no integration-step line with calls and bytes for the dynamic scene"
local=$("$bin" solve "$dynamic" --quiet --out "$out/dyn-local" 2>&1) ||
  { printf '%s\n' "$local"; fail "dynamic solve in process failed"; }
summary() { printf '%s\n' "$1" | grep -Eo '[0-9]+ steps, [0-9]+ Newton iterations, .*drift [-+.e0-9]+'; }
a=$(summary "$log" | sed 's/iterations, .* s (/iterations (/')
l=$(summary "$local" | sed 's/iterations, .* s (/iterations (/')
[ -n "$a" ] && [ "$a" = "$l" ] || fail "dynamic run across agents '$a' differs from in process '$l'"
echo "solve_cli: ok"
