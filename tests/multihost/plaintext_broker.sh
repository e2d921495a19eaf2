#!/bin/sh
# plaintext_broker.sh BIOTGRID STATE WORK
# A broker whose agents' endpoint is not loopback refuses to start without
# a key (exit 2 naming --curve-key, no store made), on an address and on
# the wildcard; an agent whose broker is not loopback likewise; with
# --insecure both run in clear and the agent registers across the bridge
# with no key; every daemon stops on SIGTERM with status 0.
set -u
bin=$1 state=$2 work=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/../broker/broker_lib.sh"
. "$here/mh_lib.sh"
mh_begin "$state" "$work"
for ep in "tcp://$IP_B:5572" "tcp://*:5572"; do
  ip netns exec "$NS_B" setpriv --pdeathsig KILL -- timeout 20 "$bin" broker --port 0 \
    --endpoint "$ep" --state-dir "$work/refused" >"$work/refused.out" 2>"$work/refused.err" </dev/null
  rc=$?
  [ $rc -eq 2 ] &&
    grep -qF -- "biotgrid broker: --curve-key: the agents' endpoint $ep is beyond loopback" "$work/refused.err"
  check $? "a plaintext broker at $ep is refused, exit 2 naming --curve-key (got $rc: $(cat "$work/refused.err"))"
done
[ ! -e "$work/refused" ]; check $? "the refused broker made no store"
ip netns exec "$NS_H1" setpriv --pdeathsig KILL -- timeout 20 "$bin" agent --broker "tcp://$IP_B:5572" \
  --name early >"$work/agent-refused.out" 2>"$work/agent-refused.err" </dev/null
rc=$?
[ $rc -eq 2 ] && grep -qF -- "--curve-key: tcp://$IP_B:5572 is beyond loopback" "$work/agent-refused.err"
check $? "an agent without keys whose broker is beyond loopback is refused (got $rc)"

ep=tcp://$IP_B:5572
mh_broker "$NS_B" broker "$work/store" --port 0 --endpoint "$ep" --insecure
check $? "with --insecure the broker starts at $ep"
grep -qF "agents: plaintext (beyond loopback: --insecure)" "$work/broker.log"
check $? "and says its agents' endpoint is plaintext beyond loopback"
mh_agent "$NS_H1" plain-h1 --listen "tcp://$IP_H1:*" --broker "$ep" --insecure --name plain-h1 \
  --services rotfit --slots 1 --cores 1 --memory 1
i=0
while [ $i -lt 100 ]; do
  bcurl -sf "$url/v1/agents" >"$work/agents.json" 2>/dev/null
  jq -e --arg ip "$IP_H1" '[.agents[] | select(.name == "plain-h1" and .alive and .address == $ip and .key == null)] | length > 0' \
    "$work/agents.json" >/dev/null 2>&1 && break
  sleep 0.1
  i=$((i + 1))
done
[ $i -lt 100 ]; check $? "a plaintext agent with --insecure registers from $IP_H1, with no key"
mh_stop_all; check $? "every daemon stopped on SIGTERM within 10 s"
for d in broker plain-h1; do
  [ "$(cat "$work/$d.rc" 2>/dev/null)" = 0 ]; check $? "$d exited 0"
done
exit $fail
