#!/bin/sh
# faults_kill.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE METHOD SERVICE AT MARKET_AUDIT
#                [MESH_DIR] [--steps N] [--iterations N]
# An agent of a running job dies (SIGKILL) and the job carries on: a local
# grid (`grid up`, ephemeral loopback ports; GRID_CONFIG has a spare agent
# of every service) runs SCENE with METHOD under the central mechanism;
# once the job has reported AT of its progress, the agent that holds its
# SERVICE contract (rotation-fit, sparse-solve or integration-step; from
# the job's contract events, its PID from the grid's state) is killed.
# Then:
#   - the job succeeds, with the energy of `biotgrid solve` on the same
#     scene to 1e-9 relative (a dynamic scene: the same steps, each step's
#     total energy to 1e-9 of the largest);
#   - its events name the lost agent and the service ("agent_lost", with
#     the settled contract), the re-purchase from another agent and its
#     cost ("rebought"), and the solve resuming on it ("resumed");
#   - report.json's faults list the loss and the replacement, its market
#     section holds the replacement's contract and spends within budget;
#   - the lost contract is settled pro rata in /v1/market/contracts.csv
#     (ended at the loss, for less than it was bought for) and the live
#     audit (MARKET_AUDIT --live) passes on the log;
#   - `grid down` leaves no process.
# Prints the time from the kill to the job computing again (the
# "resumed" event). --steps N and --iterations N override the scene's
# steps and solver cap, the same on both sides.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5 method=$6 service=$7 at=$8 audit=$9
shift 9
mesh_dir=
case ${1:-} in --*|'') ;; *) mesh_dir=$1; shift ;; esac
steps= iterations=
while [ $# -gt 1 ]; do
  case $1 in
    --steps) steps=$2 ;;
    --iterations) iterations=$2 ;;
  esac
  shift 2
done
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
contracts() { awk '/^event: / { e = $2 } /^data: / && e == "contract" { sub(/^data: /, ""); print }' "$1"; }
events_of() { awk -v k="$2" '/^event: / { e = $2 } /^data: / && e == k { sub(/^data: /, ""); print }' "$1"; }
grid_up_market "$bin" "$config" "$state"

# The scene as both sides run it: the method, and the overrides.
jq --arg m "$method" --arg s "${steps:-0}" --arg i "${iterations:-0}" '
  .solver.method = $m
  | if ($s | tonumber) > 0 then .task.steps = ($s | tonumber) else . end
  | if ($i | tonumber) > 0 then .solver.max_iterations = ($i | tonumber) else . end' \
  "$scene" >"$work/scene.json"
for f in $(jq -r '.. | objects | .file? // empty, (.mesh | strings)' "$scene" 2>/dev/null); do
  [ -f "$(dirname "$scene")/$f" ] && cp "$(dirname "$scene")/$f" "$work/"
done
mp=
[ -n "$mesh_dir" ] && mp="--mesh-path $mesh_dir"
# shellcheck disable=SC2086 # the option is two words or none
"$bin" solve "$work/scene.json" $mp --quiet --out "$work/local" >"$work/local.txt" 2>&1
# Exit 1 is a run stopped at its cap (--iterations): its report is the reference still.
[ $? -le 1 ] && [ -s "$work/local/report.json" ]
check $? "biotgrid solve (the undisturbed reference)"

# shellcheck disable=SC2086
id=$("$bin" submit "$work/scene.json" $mp --mechanism central --budget 1000 --broker "$url" \
  --json 2>"$work/submit.txt" | jq -r .id)
[ -n "$id" ] && [ "$id" != null ]; check $? "the job is accepted (${id:-none}: $(cat "$work/submit.txt"))"
# Progress AT, then the agent selling SERVICE to the job.
i=0 frac=0
while [ $i -lt 1800 ]; do
  doc=$(bcurl -sf "$url/v1/jobs/$id")
  st=$(echo "$doc" | jq -r .state)
  frac=$(echo "$doc" | jq -r '.progress.fraction // 0')
  [ "$st" = running ] && awk -v f="$frac" -v a="$at" 'BEGIN { exit !(f >= a) }' && break
  case $st in succeeded|failed|cancelled) break ;; esac
  sleep 0.1
  i=$((i + 1))
done
[ "$st" = running ]; check $? "the job runs and reaches $at of its progress (state $st, $frac)"
# The job's contracts (GET /v1/jobs/{id}: its events stream would last
# until the job ends).
victim=$(echo "$doc" | jq -r --arg s "$service" '[.contracts[] | select(.service == $s)][0].agent')
pid=$(jq -r --arg n "$victim" '.agents[] | select(.name == $n) | .pid' "$state/grid.json")
[ -n "$victim" ] && [ -n "$pid" ]; check $? "the job's $service agent is $victim (pid $pid)"
t_kill=$(now)
kill -KILL "$pid"
echo "killed $victim (pid $pid, $service) at $frac of the job"

st=$(wait_job "$url" "$id" 1200)
[ "$st" = succeeded ]; check $? "the job succeeds after losing $victim (got $st)"
[ "$st" = succeeded ] || bcurl -sf "$url/v1/jobs/$id" >&2
bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events.txt"
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"

if jq -e '.runs[0].steps | length > 0' "$work/local/report.json" >/dev/null 2>&1; then
  jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" '
    ($a[0].runs[0].steps) as $x | ($b[0].runs[0].steps) as $y
    | ([$y[].total_energy | fabs] | max) as $scale
    | ($x | length) == ($y | length) and
      all(range(0; $x | length); (($x[.].total_energy - $y[.].total_energy) | fabs) <= 1e-9 * $scale)' \
    | grep -q true
  check $? "the same steps as biotgrid solve ($(jq '.runs[0].steps | length' "$work/report.json") of $(jq '.runs[0].steps | length' "$work/local/report.json")), each step's energy to 1e-9"
else
  jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" \
    '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-9 * ($b[0].runs[0].energy | fabs)' \
    | grep -q true
  check $? "the energy equals biotgrid solve's to 1e-9 ($(jq .runs[0].energy "$work/report.json") vs $(jq .runs[0].energy "$work/local/report.json"))"
fi

lost=$(events_of "$work/events.txt" agent_lost | head -1)
[ -n "$lost" ] && echo "$lost" | jq -e --arg v "$victim" --arg s "$service" \
  '.agent == $v and .service == $s and (.reason | length) > 0 and .settled.paid >= 0 and
   .settled.quantity < .settled.of' >/dev/null
check $? "an agent_lost event names $victim and $service, why, and its contract settled pro rata ($lost)"
again=$(events_of "$work/events.txt" rebought | head -1)
[ -n "$again" ] && echo "$again" | jq -e --arg v "$victim" --arg s "$service" \
  '.service == $s and .lost == $v and .agent != $v and .cost > 0 and .spent <= .budget' >/dev/null
check $? "a rebought event names the new $service agent and its cost ($again)"
newagent=$(echo "$again" | jq -r .agent)
resumed=$(events_of "$work/events.txt" resumed | head -1)
[ -n "$resumed" ] && echo "$resumed" | jq -e --arg n "$newagent" '.agent == $n' >/dev/null
check $? "a resumed event: the solve goes on on $newagent ($resumed)"
t_resumed=$(echo "$resumed" | jq -r .time)
t_lost=$(echo "$lost" | jq -r .time)
t_bought=$(echo "$again" | jq -r .time)
awk -v k="$t_kill" -v l="$t_lost" -v b="$t_bought" -v r="$t_resumed" 'BEGIN {
  printf "from the kill: noticed after %.2f s, bought again after %.2f s, computing again after %.2f s\n",
         l - k, b - k, r - k }' | tee "$work/timing.txt"
[ -n "$resumed" ] && awk -v k="$t_kill" -v r="$t_resumed" 'BEGIN { exit !(r > k && r - k < 60) }'
check $? "the job computes again within 60 s of the kill"

jq -e --arg v "$victim" --arg n "$newagent" --arg s "$service" '
  (.faults | length) == 1 and .faults[0].lost == $v and .faults[0].service == $s and
  .faults[0].replacement.agent == $n and .faults[0].resumed_after_seconds > 0 and
  ([.market.contracts[] | select(.agent == $n and .service == $s)] | length) >= 1 and
  ([.market.contracts[] | select(.agent == $v and .service == $s and .quantity < 1)] | length) == 1 and
  .market.spent > 0 and .market.spent <= .market.budget' "$work/report.json" >/dev/null
check $? "report.json lists the fault and the replacement's contract, spent within budget"

# The log once every row is closed: the lost row settled, the audit passes.
contracts_closed "$url" "$work/contracts.csv"
bcurl -sf "$url/v1/market/agents.csv" >"$work/agents.csv"
vid=$(echo "$lost" | jq -r .agent)
vrow=$(contracts "$work/events.txt" | jq -r --arg v "$victim" --arg s "$service" \
  'select(.agent == $v and .service == $s) | .agent_id' | head -1)
awk -F, -v a="$vrow" -v s="$service" -v j="$id" '
  NR > 1 && $4 == "service" && $10 == a && $11 == s && $9 == j { n++; q = $12; d = $8 - $7 }
  END { exit !(n == 1 && q < 1 && d < 1e8) }' "$work/contracts.csv"
check $? "contracts.csv: $vid's $service row ends at the loss for the work delivered"
"$audit" --live "$work" >"$work/audit.txt" 2>&1
check $? "the live audit passes ($(cat "$work/audit.txt"))"

grid_test_end "$scripts"
exit $fail
