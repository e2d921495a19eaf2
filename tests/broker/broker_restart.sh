#!/bin/sh
# broker_restart.sh BIOTGRID WORKDIR SCENE
# A broker with no market and no agents accepts jobs and keeps them in
# allocating (nothing bought, an event says why); restarted between
# submit and poll — once by SIGTERM, once killed with SIGKILL — it still
# lists every accepted job under the same ids, none lost and none added,
# and an idempotent resubmit after the restart returns the same job.
# Once an agent registers on its market, every waiting job runs.
set -u
bin=$1 work=$2 scene=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
broker_test_begin "$work"
broker_config "$work" restart
jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "central", budget: 1000}' >"$work/submit.json"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
: >"$work/ids"
for i in 1 2 3 4 5; do
  bcurl -sf -X POST -H 'Content-Type: application/json' -H "Idempotency-Key: key-$i" \
    --data-binary @"$work/submit.json" "$url/v1/jobs" | jq -r .id >>"$work/ids"
done
[ "$(sort -u "$work/ids" | grep -c '^j')" = 5 ]; check $? "five jobs accepted"
sleep 0.5
state=$(bcurl -sf "$url/v1/jobs/$(head -1 "$work/ids")" | jq -r .state)
[ "$state" = allocating ]; check $? "without a market a job waits in allocating (got $state)"
bcurl -sf --max-time 2 "$url/v1/jobs/$(head -1 "$work/ids")/events" >"$work/events.txt"
grep -q 'no agent is registered on the market' "$work/events.txt"
check $? "its allocation event says no agent is registered on the market"

listed() { bcurl -sf "$url/v1/jobs?limit=100" | jq -r '.jobs[].id' | sort; }
stop_broker "$work" b; check $? "the broker stops on SIGTERM with status 0"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
listed >"$work/after1"
sort "$work/ids" | cmp -s - "$work/after1"; check $? "after a restart every accepted job is listed"
id=$(bcurl -sf -X POST -H 'Content-Type: application/json' -H "Idempotency-Key: key-3" \
  --data-binary @"$work/submit.json" "$url/v1/jobs" | jq -r .id)
[ "$id" = "$(sed -n 3p "$work/ids")" ]; check $? "an idempotent resubmit after the restart returns the same job"

pid=$(cut -d' ' -f3 "$work/b.ready")
kill -KILL "$pid"
i=0
while [ ! -s "$work/b.rc" ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
listed >"$work/after2"
sort "$work/ids" | cmp -s - "$work/after2"; check $? "after SIGKILL and a restart every accepted job is listed"
sleep 0.5
# Each waiting job holds one of the broker's max_jobs (default 4) places.
states=$(bcurl -sf "$url/v1/jobs?limit=100" | jq -r '[.jobs[].state] | sort | join(",")')
[ "$states" = allocating,allocating,allocating,allocating,queued ]
check $? "the jobs are picked up again, 4 at a time (states: $states)"

# The waiting jobs are bought and run once an agent registers: none of
# them was given up while the market was empty. The agent sells 4 cores
# (a rotation fit holds 1, a sparse solve 2), enough for one job at a time
# whatever the test machine has. No load slope: its asks do not rise with
# the slots in use, so the prices read when it registers (jobs are bought
# at once, and on a loaded machine the first read can come after a busy
# heartbeat) are the idle ones the end is compared with.
endpoint=$(cut -d' ' -f2 "$work/b.ready")
mkdir -p "$work/agents"
( "$bin" agent --listen 'tcp://127.0.0.1:*' --services rotfit,solve --slots 4 --cores 4 --name a1 \
    --load-slope 0 --broker "$endpoint" --ready-file "$work/agents/a1.ready" \
    >"$work/agents/a1.log" 2>&1 </dev/null
  echo $? >"$work/agents/a1.rc" ) >/dev/null 2>&1 </dev/null &
trap 'sh "$here/../agents/stop_agents.sh" "$work/agents" >/dev/null 2>&1; stop_broker "$work" b; exit 1' INT TERM
prices() { bcurl -sf "$url/v1/agents" | jq -c '[.agents[] | select(.source == "market" and (.services | length) > 0) | .prices["rotation-fit"], .prices["sparse-solve"]]'; }
i=0
while [ "$(prices)" = "[]" ] && [ $i -lt 100 ]; do sleep 0.05; i=$((i + 1)); done
before=$(prices)
: >"$work/finals"
for id in $(cat "$work/ids"); do wait_job "$url" "$id" 120 >>"$work/finals"; done
finals=$(sort -u "$work/finals" | paste -sd, -)
[ "$finals" = succeeded ]; check $? "once an agent registers every waiting job is bought and succeeds (states: $finals)"
# Five jobs later the idle seller asks what it asked before, within 10 %:
# its floor is its own cost (1) plus a contract's resources at the
# expected rates (0.05 for a rotation fit, 0.12 for a solve), and the
# rates it learns are resource asks, at most 1.5 times the idle ones at
# full load. Bids of the whole service surplus on layer 1, learnt back
# into the floor, had raised them from 1.26 to over 300 in five jobs.
i=0
while [ "$(market_sellers "$url" idle)" != 1 ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
sleep 1 # a heartbeat (0.5 s) brings the idle seller's prices
after=$(prices)
jq -n --argjson b "$before" --argjson a "$after" \
  '$b | length == 2 and ([range(2)] | all($a[.] <= 1.1 * $b[.] and $a[.] >= $b[.] / 1.1))' | grep -q true
check $? "the seller's asking prices stay where they were (before $before, after $after)"
stop_broker "$work" b; check $? "the broker stops again"
sh "$here/../agents/stop_agents.sh" "$work/agents" >/dev/null; check $? "the agent stops with status 0"
pid=$(cut -d' ' -f3 "$work/b.ready")
if kill -0 "$pid" 2>/dev/null; then echo "FAIL: broker $pid left" >&2; fail=1; fi
exit $fail
