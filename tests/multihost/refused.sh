#!/bin/sh
# refused.sh BIOTGRID STATE WORK
# Strangers on the network (its own namespaces, netns.sh): a CURVE
# broker admits the agent whose key it lists (from another host) and
# refuses, from a third host, an agent with a key it does not list and a
# plaintext agent; the broker logs each refusal with the peer's address
# (and the key when one was shown), the keyed stranger is told its key
# was refused, neither is listed, and every daemon, refused or not,
# stops on SIGTERM with status 0.
set -u
bin=$1 state=$2 work=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/../broker/broker_lib.sh"
. "$here/mh_lib.sh"
mh_begin "$state" "$work"
keys=$work/keys
mh_keys "$keys" broker agent-h1 stranger
mkdir -p "$work/authorized"
cp "$keys/agent-h1.pub" "$work/authorized/"
ep=tcp://$IP_B:5571
mh_broker "$NS_B" broker "$work/store" --port 0 --endpoint "$ep" \
  --curve-key "$keys/broker.key" --authorized-agents "$work/authorized"
check $? "a CURVE broker on $NS_B at $ep"
mh_agent "$NS_H1" agent-h1 --listen "tcp://$IP_H1:*" --broker "$ep" \
  --curve-key "$keys/agent-h1.key" --broker-key "$keys/broker.pub" --services rotfit --slots 1
mh_agent "$NS_X" stranger --listen "tcp://$IP_X:*" --broker "$ep" \
  --curve-key "$keys/stranger.key" --broker-key "$keys/broker.pub" --services rotfit --slots 1
mh_agent "$NS_X" plain --listen "tcp://$IP_X:*" --broker "$ep" --insecure --name plain \
  --services rotfit --slots 1

wait_for "$work/broker.log" 15 "refused $IP_X: CURVE key $(cat "$keys/stranger.pub") is not among the authorized agents' keys"
check $? "the broker logs the stranger's key refusal with its address and key"
wait_for "$work/stranger.log" 15 "broker $ep: refused this process's CURVE key (ZAP status 400)"
check $? "the stranger is told its key was refused"
# A plaintext peer may leave before its address is read (the line says
# so); it connects again every 10 s while unregistered: wait for a line
# with its address.
wait_for "$work/broker.log" 40 "agents' endpoint $ep: refused $IP_X:"
check $? "the broker logs the plaintext agent's refusal with its address"
grep -F "agents' endpoint $ep: refused $IP_X:" "$work/broker.log" | grep -q "(no key shown)"
check $? "the plaintext refusal says no key was shown"
i=0
while [ $i -lt 100 ]; do
  bcurl -sf "$url/v1/agents" >"$work/agents.json" 2>/dev/null
  jq -e '[.agents[] | select(.name == "agent-h1" and .alive)] | length > 0' "$work/agents.json" \
    >/dev/null 2>&1 && break
  sleep 0.1
  i=$((i + 1))
done
[ "$(jq -r '[.agents[].name] | unique | join(",")' "$work/agents.json")" = agent-h1 ]
check $? "the broker lists agent-h1 alone (got $(jq -r '[.agents[].name] | unique | join(",")' "$work/agents.json"))"
grep "refused" "$work/broker.log" | sed 's/^/  broker log: /'

mh_stop_all; check $? "every daemon stopped on SIGTERM within 10 s, the refused ones too"
for d in broker agent-h1 stranger plain; do
  [ "$(cat "$work/$d.rc" 2>/dev/null)" = 0 ]; check $? "$d exited 0"
done
exit $fail
