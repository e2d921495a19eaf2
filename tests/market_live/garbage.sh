#!/bin/sh
# garbage.sh BIOTGRID GARBAGE_PEER WORK
# Malformed market messages against real processes on loopback: a
# `biotgrid broker` (ephemeral ports) gets them on its agent endpoint and
# a `biotgrid agent --broker` gets them from a peer posing as its broker.
# Each answers every one with an ERROR naming what is wrong and keeps
# serving: the broker still registers agents and answers /healthz, the
# agent's resource seller still confirms an order (garbage_peer checks
# the answers). Every process started here is stopped; none may be left.
set -u
BIOTGRID=$1 PEER=$2 WORK=$3
here=$(cd "$(dirname "$0")/../broker" && pwd)
. "$here/broker_lib.sh"
rm -rf "$WORK" && mkdir -p "$WORK/state" || exit 1
fail=0
AGENT=""
cleanup() {
    [ -n "$AGENT" ] && kill "$AGENT" 2>/dev/null && wait "$AGENT" 2>/dev/null
    stop_broker "$WORK" broker >/dev/null 2>&1
}
trap cleanup EXIT INT TERM

cat >"$WORK/broker.json" <<JSON
{"name": "garbage", "port": 0, "endpoint": "tcp://127.0.0.1:*", "state_dir": "$WORK/state"}
JSON
start_broker "$BIOTGRID" "$WORK" broker "$WORK/broker.json" || exit 1
URL=$(cut -d' ' -f1 "$WORK/broker.ready") EP=$(cut -d' ' -f2 "$WORK/broker.ready")
BPID=$(cut -d' ' -f3 "$WORK/broker.ready")
"$PEER" broker "$EP"
check $? "the broker answered every malformed message and still registers agents"
kill -0 "$BPID" 2>/dev/null
check $? "the broker is still running"
bcurl -sf "$URL/healthz" >/dev/null
check $? "the broker still answers /healthz"
stop_broker "$WORK" broker
check $? "the broker stopped cleanly (exit 0)"

"$PEER" agent "$WORK/peer.endpoint" &
PEERPID=$!
i=0
while [ ! -s "$WORK/peer.endpoint" ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
if [ -s "$WORK/peer.endpoint" ]; then
    "$BIOTGRID" agent --name g1 --services rotfit --slots 1 --broker "$(cat "$WORK/peer.endpoint")" \
        --cores 1 --memory 2 >"$WORK/agent.log" 2>&1 &
    AGENT=$!
fi
wait "$PEERPID"
check $? "the agent answered every malformed message and its resource seller still sells"
if [ -n "$AGENT" ]; then
    kill -0 "$AGENT" 2>/dev/null
    check $? "the agent is still running"
    kill "$AGENT" 2>/dev/null
    wait "$AGENT" 2>/dev/null
    kill -0 "$AGENT" 2>/dev/null && { echo "FAIL: agent $AGENT is still running"; fail=1; }
    AGENT=""
fi
if grep -l -E "Sanitizer|runtime error" "$WORK"/*.log 2>/dev/null; then
    echo "FAIL: a process reported a sanitizer error"; fail=1
fi
exit $fail
