#!/bin/sh
# reference_overlap.sh BIOTGRID AGENT_SCRIPTS WORKDIR SCENE MESH_DIR
# Issue 29.3: a static job whose scene asks for a Newton reference solves
# it in the coordinator alongside the run on the agents, not before it.
# A broker with a fixed pool (one rotation-fit agent: the run is then
# `solve`'s to the bit) runs SCENE (the bunny edit, its run capped at 4
# Newton iterations; the reference is solved in full) and its events show
# the overlap: the run's iteration 0 was reported before the reference
# had ended (its progress event says "error": null and precedes the
# `reference` event). The error column measured after both ended equals
# `biotgrid solve`'s (which solves the reference first) point for point,
# as do the energies. A job cancelled while both go on ends cancelled,
# the next job succeeds, and the broker exits 0. Before the change there was no `reference` event
# and iteration 0 had its error. Every process started here is stopped.
set -u
bin=$1 scripts=$2 work=$3 scene=$4 mesh_dir=$5
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
broker_agents_test_begin "$work" "$scripts"

sh "$scripts/start_agents.sh" "$bin" "$work/agents" r1:rotfit sv:solve ig:integ \
  >"$work/agents.txt" || exit 1
ep() { cut -d' ' -f1 "$work/agents/$1.ready"; }
broker_config "$work" overlap "$(jq -n --arg r "$(ep r1)" --arg s "$(ep sv)" --arg i "$(ep ig)" \
  '{agents: [{endpoint: $r, services: "rotfit"}, {endpoint: $s, services: "solve"},
             {endpoint: $i, services: "integ"}]}')"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")

# The mesh is found by name on MESH_DIR, by `submit` and by `solve` alike.
jq '.solver.max_iterations.newton = 4' "$scene" >"$work/scene.json" || exit 1
id=$("$bin" submit "$work/scene.json" --mesh-path "$mesh_dir" --mechanism posted --budget 100 \
  --broker "$url" --json 2>"$work/submit.txt" | jq -r '.id // empty')
[ -n "$id" ]; check $? "the job is submitted ($id)"
state=$(wait_job "$url" "$id" 300)
[ "$state" = succeeded ]; check $? "job $id succeeded (got $state)"
bcurl -sf --max-time 30 "$url/v1/jobs/$id/events" >"$work/events.txt"
# The events as one JSON array of {event, data}, in the stream's order.
awk '/^event: / { e = substr($0, 8) } /^data: / { print "{\"event\":\"" e "\",\"data\":" substr($0, 7) "}" }' \
  "$work/events.txt" | jq -s . >"$work/events.json"
jq -e '[.[] | select(.event == "reference")] | length == 1 and .[0].data.ok' "$work/events.json" \
  >/dev/null
check $? "one reference event, the reference solved"
jq -e '(map(.event == "reference") | index(true)) as $r
       | (map(.event == "progress" and .data.iteration == 0) | index(true)) as $p
       | $p != null and $r != null and $p < $r and .[$p].data.error == null' "$work/events.json" \
  >/dev/null
check $? "the run's iteration 0 was reported (error null) before the reference ended: $(jq -c '[.[] | select(.event == "reference" or (.event == "progress" and .data.iteration == 0)) | .event]' "$work/events.json")"

bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"
BIOTGRID_MESH_PATH=$mesh_dir "$bin" solve "$work/scene.json" --quiet --out "$work/local" \
  >"$work/local.txt" 2>&1
[ -f "$work/local/report.json" ]; check $? "biotgrid solve wrote its report"
jq -e --slurpfile l "$work/local/report.json" '
  [.runs[0].trace[] | [.iteration, .energy, .error]] as $g
  | [$l[0].runs[0].trace[] | [.iteration, .energy, .error]] as $s
  | ($g | length) > 1 and $g == $s and all($g[]; .[2] != null)' "$work/report.json" >/dev/null
check $? "the error column and the energies equal solve's, point for point: $(jq -c '[.runs[0].trace[].error]' "$work/report.json") against $(jq -c '[.runs[0].trace[].error]' "$work/local/report.json")"

# A cancel while the reference and the run go on stops both: the job ends
# cancelled, its coordinator joins the reference thread (the next job
# runs and succeeds), and the broker exits 0 (under the sanitizers: no
# leak, no thread left).
submit() {
  "$bin" submit "$1" --mesh-path "$mesh_dir" --mechanism posted --budget 100 --broker "$url" \
    --json 2>>"$work/submit.txt" | jq -r '.id // empty'
}
id2=$(submit "$scene")
i=0
while [ "$(bcurl -sf "$url/v1/jobs/$id2" | jq -r .state)" != running ] && [ $i -lt 600 ]; do
  sleep 0.05
  i=$((i + 1))
done
code=$(bcurl -s -o "$work/cancel.json" -w '%{http_code}' -X POST "$url/v1/jobs/$id2/cancel")
[ "$code" = 200 ]; check $? "job $id2 is cancelled while it runs (answer $code)"
state=$(wait_job "$url" "$id2" 120)
[ "$state" = cancelled ]; check $? "job $id2 stays cancelled (got $state)"
echo "info: job $id2's reference: $(bcurl -sf --max-time 10 "$url/v1/jobs/$id2/events" | grep -A1 '^event: reference' | sed -n 's/^data: //p')"
id3=$(submit "$work/scene.json")
state=$(wait_job "$url" "$id3" 300)
[ "$state" = succeeded ]; check $? "the next job $id3 runs and succeeds (got $state)"
trap - EXIT
stop_broker "$work" b || fail=1
sh "$scripts/stop_agents.sh" "$work/agents" >/dev/null || fail=1
exit $fail
