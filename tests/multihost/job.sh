#!/bin/sh
# job.sh BIOTGRID STATE WORK SCENE
# A job across hosts (its own namespaces, netns.sh): a CURVE broker
# on one host, an agent on each of two others, each with its own key in
# the broker's allowlist and each host selling its own cores; the job's
# rotation fit runs on both hosts and its energy is `biotgrid solve`'s in
# process (1e-10 relative) and its bytes crossed the bridge's port of
# each agent's host; /v1/agents shows each agent with its host's
# address and its key; every daemon stops on SIGTERM with status 0.
set -u
bin=$1 state=$2 work=$3 scene=$4
here=$(cd "$(dirname "$0")" && pwd)
. "$here/../broker/broker_lib.sh"
. "$here/mh_lib.sh"
mh_begin "$state" "$work"
keys=$work/keys
mh_keys "$keys" broker agent-h1 agent-h2
mkdir -p "$work/authorized"
cp "$keys/agent-h1.pub" "$keys/agent-h2.pub" "$work/authorized/"
ep=tcp://$IP_B:5570
mh_broker "$NS_B" broker "$work/store" --port 0 --endpoint "$ep" \
  --curve-key "$keys/broker.key" --authorized-agents "$work/authorized"
check $? "a CURVE broker on $NS_B at $ep"
for h in h1 h2; do
  eval "ns=\$NS_$(echo $h | tr a-z A-Z) ip=\$IP_$(echo $h | tr a-z A-Z)"
  services=rotfit,solve
  [ $h = h2 ] && services=rotfit,integ
  mh_agent "$ns" agent-$h --listen "tcp://$ip:*" --broker "$ep" --curve-key "$keys/agent-$h.key" \
    --broker-key "$keys/broker.pub" --services $services --slots 2 --cores 2 --memory 8
done
# Both agents sell services, and each host its cores (one resource seller each).
i=0
while [ $i -lt 150 ]; do
  bcurl -sf "$url/v1/agents" >"$work/agents.json" 2>/dev/null
  s=$(jq '[.agents[] | select(.alive and (.services | length) > 0)] | length' "$work/agents.json" 2>/dev/null)
  r=$(jq '[.agents[] | select(.alive and (.services | length) == 0)] | length' "$work/agents.json" 2>/dev/null)
  [ "${s:-0}" -eq 2 ] && [ "${r:-0}" -eq 2 ] && break
  sleep 0.1
  i=$((i + 1))
done
[ "${s:-0}" -eq 2 ] && [ "${r:-0}" -eq 2 ]
check $? "both agents registered across the bridge, each host selling its cores (got $s, $r)"
for h in h1 h2; do
  eval "ip=\$IP_$(echo $h | tr a-z A-Z)"
  jq -e --arg n agent-$h --arg ip "$ip" --arg key "$(cat "$keys/agent-$h.pub")" \
    '[.agents[] | select(.name == $n and .address == $ip and .key == $key and (.endpoint | startswith("tcp://" + $ip + ":")))] | length == 2' \
    "$work/agents.json" >/dev/null
  check $? "/v1/agents: agent-$h from $ip with its key, both its roles"
done

# The bridge's counters: the job's traffic must cross it, port by port.
port_bytes() { ip -n "$NS_SW" -s -j link show "v$1" | jq '.[0].stats64.rx.bytes + .[0].stats64.tx.bytes'; }
for h in h1 h2; do eval "before_$h=\$(port_bytes $h)"; done
jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 100}' >"$work/submit.json"
id=$(submit_job "$url" "$work/submit.json")
st=$(wait_job "$url" "$id" 300)
[ "$st" = succeeded ]; check $? "the job succeeded (got $st)"
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"
"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1
same_energy "$work/report.json" "$work/local/report.json"
check $? "its energy is the in-process solve's (1e-10 relative): $(jq .runs[0].energy "$work/report.json") vs $(jq .runs[0].energy "$work/local/report.json")"
for ip in "$IP_H1" "$IP_H2"; do
  jq -e --arg p "tcp://$ip:" \
    '[.agents[] | select(.service == "rotation-fit" and .calls > 0 and (.endpoint | startswith($p)))] | length == 1' \
    "$work/report.json" >/dev/null
  check $? "the rotation fit computed on the host at $ip"
done
for h in h1 h2; do
  eval "b=\$before_$h"
  a=$(port_bytes $h)
  sent=$(jq '[.agents[] | select(.endpoint | startswith("tcp://" + $ip + ":")) | .bytes_sent] | add // 0' \
    --arg ip "$(eval echo \$IP_$(echo $h | tr a-z A-Z))" "$work/report.json")
  [ $((a - b)) -ge "${sent%.*}" ] && [ "${sent%.*}" -gt 0 ]
  check $? "the bridge port of $h carried the job's traffic to it ($((a - b)) bytes >= $sent sent)"
done
jq -e '[.agents[] | select(.service == "sparse-solve" and .calls > 0)] | length == 1' \
  "$work/report.json" >/dev/null
check $? "the sparse solve computed on a host of its own"

mh_stop_all; check $? "every daemon stopped on SIGTERM within 10 s"
for d in broker agent-h1 agent-h2; do
  [ "$(cat "$work/$d.rc" 2>/dev/null)" = 0 ]; check $? "$d exited 0"
done
exit $fail
