#!/bin/sh
# grid_truth.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE
# The grid commands tell the truth about the processes, whatever the
# spelling of --state (./g, g, /abs/g, g/. name one grid):
# - `status` says what really runs: after SIGKILL of the broker and an
#   agent it names both "not running", says "degraded" and exits 1;
# - `up` again keeps what runs and starts what is missing: the broker on
#   the endpoint and REST port it had, with its store and tokens, so the
#   kept agents sell on its market again and a job succeeds;
# - `down` signals a recorded PID only while it is the recorded process
#   (PID and start time): a PID now held by another process is left alone
#   and reported; it says what it stopped, and nothing of the grid is left.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
cd "$work" || exit 1
trap '"$bin" grid down --state "$work/g" >/dev/null 2>&1; [ -n "${sleeper:-}" ] && kill "$sleeper"; exit 1' INT TERM
"$bin" grid up "$config" --state ./g --broker-port 0 --broker-endpoint 'tcp://127.0.0.1:*' \
  >up1.txt 2>&1
check $? "grid up --state ./g"
state=$work/g
grid_token "$state"
url=$(jq -r .broker.url "$state/grid.json")
"$bin" grid status --state g >status1.txt 2>&1
check $? "grid status --state g (another spelling) finds it up"
grep -q "^grid local: up$" status1.txt; check $? "and says so"

bpid=$(jq -r .broker.pid "$state/grid.json")
apid=$(jq -r '.agents[] | select(.name == "rotfit-1") | .pid' "$state/grid.json")
kill -KILL "$bpid" "$apid"
sleep 0.3
"$bin" grid status --state "$state/." >status2.txt 2>&1
rc=$?
cat status2.txt
[ $rc -eq 1 ] && grep -q "^broker .* not running" status2.txt &&
  grep -q "^rotfit-1 .* not running" status2.txt && grep -q "^rotfit-2 .* up," status2.txt &&
  grep -q "degraded" status2.txt
check $? "after SIGKILL of the broker and rotfit-1, status names both not running, degraded, exit 1 (exit $rc)"

"$bin" grid up "$config" --state "$state" >up2.txt 2>&1
rc=$?
cat up2.txt
[ $rc -eq 0 ] && grep -q "3 processes kept, 2 started" up2.txt &&
  grep -q "^rotfit-2 .*(kept: it runs)" up2.txt && ! grep -q "^rotfit-1 .*kept" up2.txt
check $? "grid up again keeps the 3 running agents and starts the broker and rotfit-1 (exit $rc)"
[ "$(jq -r .broker.url "$state/grid.json")" = "$url" ]
check $? "the broker is back on its REST URL ($url)"
"$bin" grid status --state "$state" >status3.txt 2>&1
check $? "grid status: up again"
code=$(bcurl -s -o /dev/null -w '%{http_code}' "$url/v1/jobs")
[ "$code" = 200 ]; check $? "the token grid up wrote still works (HTTP $code)"
# The kept agents re-register with the restarted broker by themselves.
i=0
while [ "$(market_sellers "$url" service)" != 4 ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
[ "$(market_sellers "$url" service)" = 4 ]; check $? "all 4 agents sell on the restarted broker's market"
jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "central", budget: 1000}' >submit.json
id=$(submit_job "$url" submit.json)
st=$(wait_job "$url" "$id" 120)
[ "$st" = succeeded ]; check $? "a job on the repaired grid succeeds (got $st)"

# A record whose PID now belongs to another process: left alone.
cp "$state/grid.json" saved.json
sleep 300 &
sleeper=$!
"$bin" grid down --state ./g >down1.txt 2>&1
check $? "grid down"
cat down1.txt
[ "$(grep -c "stopped (pid [0-9]*, SIGTERM)$" down1.txt)" = 5 ]
check $? "down says it stopped the broker and the 4 agents by SIGTERM"
sh "$scripts/no_agents_left.sh" "$state"; check $? "no process of the grid is left"
[ ! -e "$state/grid.json" ]; check $? "the state file is gone once nothing runs"
jq --argjson p "$sleeper" '.agents[0].pid = $p' saved.json >"$state/grid.json"
"$bin" grid down --state g >down2.txt 2>&1
rc=$?
cat down2.txt
kill -0 "$sleeper" 2>/dev/null && [ $rc -eq 0 ] &&
  grep -q "^rotfit-1 *was not running (pid $sleeper is another process now)" down2.txt
check $? "a recorded PID held by another process is not signalled, and down says so"
kill "$sleeper"
sleeper=
exit $fail
