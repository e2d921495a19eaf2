#!/bin/sh
# grid_jobs.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE
# `grid up` starts the agents and the broker (ephemeral loopback ports),
# records the broker in the state file and `grid status` shows it; a job
# submitted to that broker gives `biotgrid solve`'s energy (1e-10
# relative); `grid down` stops the broker and the agents and no process
# of the grid is left.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
"$bin" grid up "$config" --state "$state" --broker-port 0 \
  --broker-endpoint 'tcp://127.0.0.1:*' >"$work/up.txt" 2>&1
check $? "grid up"
cat "$work/up.txt"
grid_token "$state"
url=$(jq -r '.broker.url // empty' "$state/grid.json" 2>/dev/null)
[ -n "$url" ]; check $? "the state file records the broker ($url)"
"$bin" grid status --state "$state" >"$work/status.txt" 2>&1
grep -q "^broker .* up, REST $url" "$work/status.txt"; check $? "grid status shows the broker up"

jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 100}' >"$work/submit.json"
id=$(bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$work/submit.json" \
  "$url/v1/jobs" | jq -r .id)
st=$(wait_job "$url" "$id" 300)
[ "$st" = succeeded ]; check $? "the job on the grid succeeded (got $st)"
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"
"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1
jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" \
  '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' \
  | grep -q true
check $? "its energy equals biotgrid solve's (1e-10 relative)"
used=$(jq '[.agents[] | select(.calls > 0)] | length' "$work/report.json")
[ "$used" -ge 2 ]; check $? "the job ran on $used of the grid's agents"

grid_test_end "$scripts"
grep -q "^broker  *stopped (pid [0-9]*, SIGTERM)$" "$work/down.txt"; check $? "grid down stopped the broker by SIGTERM"
exit $fail
