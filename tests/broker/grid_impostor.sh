#!/bin/sh
# grid_impostor.sh BIOTGRID AGENT_SCRIPTS WORKDIR SCENE
# Issue 26's "anyone can become an agent" on a local grid without keys
# (loopback, "security" "none"): a second agent taking the name of one of
# the grid's agents is refused by the broker, which logs the refusal with
# its address (and "no key: plaintext"), the impostor is told, /v1/agents
# keeps the name on the grid's own endpoint, a job never computes on the
# impostor; an agent with a name of its own registers and `grid status`
# lists it (not started by this grid, no key); every daemon stops.
set -u
bin=$1 scripts=$2 work=$3 scene=$4
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
others=""
stop_others() {
  for p in $others; do kill -TERM "$p" 2>/dev/null; done
  for p in $others; do
    i=0
    while kill -0 "$p" 2>/dev/null && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
    ! kill -0 "$p" 2>/dev/null || { kill -KILL "$p" 2>/dev/null; return 1; }
  done
  others=""
}
trap 'stop_others; "$bin" grid down --state "$state" >/dev/null 2>&1' EXIT
trap 'exit 1' INT TERM HUP

cat >"$work/open.json" <<EOF
{
  "name": "open",
  "agents": [
    {"name": "rotfit-1", "services": "rotfit", "slots": 2},
    {"name": "rotfit-2", "services": "rotfit", "slots": 2},
    {"name": "solve-1", "services": "solve,integ", "slots": 2}
  ],
  "broker": {"port": 0, "endpoint": "tcp://127.0.0.1:*"},
  "host": {"cores": 4, "memory": 16}
}
EOF
"$bin" grid up "$work/open.json" --state "$state" >"$work/up.txt" 2>&1
check $? "grid up without keys on loopback"
grid_token "$state"
url=$(jq -r .broker.url "$state/grid.json") ep=$(jq -r .broker.endpoint "$state/grid.json")
own=$(jq -r '.agents[] | select(.name == "rotfit-2") | .endpoint' "$state/grid.json")

# The impostor: rotfit-2's name, a floor far below the grid's (it would win).
"$bin" agent --broker "$ep" --name rotfit-2 --services rotfit --slots 4 --floor 0.0001 --cores 0 \
  --ready-file "$work/impostor.ready" >"$work/impostor.log" 2>&1 </dev/null &
others="$others $!"
"$bin" agent --broker "$ep" --name extra-1 --services rotfit --slots 3 --cores 0 \
  >"$work/extra-1.log" 2>&1 </dev/null &
others="$others $!"
wait_for_text() {
  i=0
  while ! grep -qF -- "$2" "$1" 2>/dev/null && [ $i -lt $(($3 * 10)) ]; do sleep 0.1; i=$((i + 1)); done
  grep -qF -- "$2" "$1" 2>/dev/null
}
wait_for_text "$state/broker.log" \
  "refused the registration of agent 'rotfit-2' from 127.0.0.1 (no key: plaintext): the name 'rotfit-2' is registered by another agent" 15
check $? "the broker refuses a second rotfit-2 and logs it with its address"
wait_for_text "$work/impostor.log" "the broker says: registration refused" 15
check $? "the impostor is told"
i=0
while [ $i -lt 100 ]; do
  bcurl -sf "$url/v1/agents" >"$work/agents.json" 2>/dev/null
  jq -e '[.agents[] | select(.name == "extra-1" and .alive)] | length > 0' "$work/agents.json" \
    >/dev/null 2>&1 && break
  sleep 0.1
  i=$((i + 1))
done
[ "$(jq -r '[.agents[] | select(.name == "rotfit-2" and (.services | length) > 0) | .endpoint] | join(" ")' \
  "$work/agents.json")" = "$own" ]
check $? "/v1/agents: rotfit-2 once, on the grid's own endpoint $own"
imp_ep=$(cut -d' ' -f1 "$work/impostor.ready" 2>/dev/null)
[ -n "$imp_ep" ] && ! grep -qF "$imp_ep" "$work/agents.json"
check $? "the impostor's endpoint ($imp_ep) is not listed"
"$bin" grid status --state "$state" >"$work/status.txt" 2>&1
check $? "grid status: up"
cat "$work/status.txt"
grep -q "^extra-1 .*registered from 127.0.0.1, not started by this grid: up, 3 of 3 slots free, no key (plaintext)" \
  "$work/status.txt"
check $? "grid status lists extra-1, which the grid did not start, with its address and no key"
[ "$(grep -c '^rotfit-2 ' "$work/status.txt")" = 1 ]
check $? "grid status lists rotfit-2 once"

BIOTGRID_GRID_DIR=$state "$bin" submit "$scene" --mechanism posted --budget 100 \
  --out "$work/job" >"$work/submit.txt" 2>&1
check $? "a job on the grid succeeded"
[ -n "$imp_ep" ] && ! jq -e --arg e "$imp_ep" '[.agents[] | select(.endpoint == $e)] | length > 0' \
  "$work/job/report.json" >/dev/null
check $? "the job computed nowhere on the impostor"
stop_others; check $? "the impostor and extra-1 stopped on SIGTERM"
grid_test_end "$scripts"
exit $fail
