#!/bin/sh
# broker_restart.sh BIOTGRID WORKDIR SCENE
# A broker with no market and no agents accepts jobs and keeps them in
# allocating (nothing bought, an event says why); restarted between
# submit and poll — once by SIGTERM, once killed with SIGKILL — it still
# lists every accepted job under the same ids, none lost and none added,
# and an idempotent resubmit after the restart returns the same job.
set -u
bin=$1 work=$2 scene=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
rm -rf "$work"
mkdir -p "$work"
fail=0
trap 'stop_broker "$work" b; exit 1' INT TERM
cat >"$work/broker.json" <<JSON
{"name": "restart", "port": 0, "endpoint": "tcp://127.0.0.1:*", "state_dir": "$work/state"}
JSON
jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "central", budget: 10}' >"$work/submit.json"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
: >"$work/ids"
for i in 1 2 3 4 5; do
  curl -sf -X POST -H 'Content-Type: application/json' -H "Idempotency-Key: key-$i" \
    --data-binary @"$work/submit.json" "$url/v1/jobs" | jq -r .id >>"$work/ids"
done
[ "$(sort -u "$work/ids" | grep -c '^j')" = 5 ]; check $? "five jobs accepted"
sleep 0.5
state=$(curl -sf "$url/v1/jobs/$(head -1 "$work/ids")" | jq -r .state)
[ "$state" = allocating ]; check $? "without a market a job waits in allocating (got $state)"
curl -sf --max-time 2 "$url/v1/jobs/$(head -1 "$work/ids")/events" >"$work/events.txt"
grep -q 'no agent is registered on the market' "$work/events.txt"
check $? "its allocation event says no agent is registered on the market"

listed() { curl -sf "$url/v1/jobs?limit=100" | jq -r '.jobs[].id' | sort; }
stop_broker "$work" b; check $? "the broker stops on SIGTERM with status 0"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
listed >"$work/after1"
sort "$work/ids" | cmp -s - "$work/after1"; check $? "after a restart every accepted job is listed"
id=$(curl -sf -X POST -H 'Content-Type: application/json' -H "Idempotency-Key: key-3" \
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
states=$(curl -sf "$url/v1/jobs?limit=100" | jq -r '[.jobs[].state] | unique | join(",")')
[ "$states" = allocating ]; check $? "the jobs are picked up again (states: $states)"
stop_broker "$work" b; check $? "the broker stops again"
pid=$(cut -d' ' -f3 "$work/b.ready")
if kill -0 "$pid" 2>/dev/null; then echo "FAIL: broker $pid left" >&2; fail=1; fi
exit $fail
