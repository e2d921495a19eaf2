#!/bin/sh
# grid_curve.sh BIOTGRID AGENT_SCRIPTS WORKDIR SCENE
# A local grid with "security": "curve": `grid up` makes a key pair per
# process in the state folder (secret keys 0600) and the broker's
# allowlist of its agents' public keys, the broker speaks CURVE, `grid
# status` pings the agents over CURVE and lists an agent the grid did not
# start (registered with its own key, added to the allowlist) with its
# address and key, a job succeeds with `biotgrid solve`'s energy, a second
# `up` keeps the keys; without keys an endpoint beyond loopback, and CURVE
# without a broker, are refused with exit 2 naming the field; `grid down`
# leaves no process.
set -u
bin=$1 scripts=$2 work=$3 scene=$4
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
remote=""
trap '[ -n "$remote" ] && kill -TERM $remote 2>/dev/null; "$bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM

cat >"$work/curve.json" <<EOF
{
  "name": "sealed",
  "security": "curve",
  "agents": [
    {"name": "rotfit-1", "services": "rotfit", "slots": 2},
    {"name": "solve-1", "services": "solve,integ", "slots": 2}
  ],
  "broker": {"port": 0, "endpoint": "tcp://127.0.0.1:*"},
  "host": {"cores": 4, "memory": 16}
}
EOF
"$bin" grid up "$work/curve.json" --state "$state" >"$work/up.txt" 2>&1
check $? "grid up with security curve"
cat "$work/up.txt"
for n in broker rotfit-1 solve-1; do
  [ "$(stat -c %a "$state/keys/$n.key")" = 600 ] && [ -s "$state/keys/$n.pub" ]
  check $? "a key pair for $n in the state folder, the secret key 0600"
done
for n in rotfit-1 solve-1; do
  cmp -s "$state/keys/$n.pub" "$state/authorized/$n.pub"
  check $? "$n's public key is in the broker's allowlist"
done
[ "$(jq -r .security "$state/grid.json")" = curve ]; check $? "the state file records CURVE"
grep -qF "agents: CURVE, public key $(cat "$state/keys/broker.pub"), 2 authorized" \
  "$state/broker.log"
check $? "the broker speaks CURVE with the grid's key, two agents authorized"
grid_token "$state"
url=$(jq -r .broker.url "$state/grid.json") ep=$(jq -r .broker.endpoint "$state/grid.json")

# An agent the grid did not start, with its own key put in the allowlist.
"$bin" keygen "$work/remote-1" >/dev/null && cp "$work/remote-1.pub" "$state/authorized/"
"$bin" agent --broker "$ep" --curve-key "$work/remote-1.key" --broker-key "$state/keys/broker.pub" \
  --services rotfit --slots 3 --cores 0 >"$work/remote-1.log" 2>&1 </dev/null &
remote=$!
i=0
while [ $i -lt 100 ]; do
  bcurl -sf "$url/v1/agents" | jq -e '[.agents[] | select(.name == "remote-1" and .alive)] | length > 0' \
    >/dev/null && break
  sleep 0.1
  i=$((i + 1))
done
"$bin" grid status --state "$state" >"$work/status.txt" 2>&1
check $? "grid status: up"
cat "$work/status.txt"
grep -q "^rotfit-1 .* up, 0 jobs, 2 of 2 slots free" "$work/status.txt"
check $? "status pings the grid's agents over CURVE"
grep -q "^broker .* up, REST $url, CURVE$" "$work/status.txt"; check $? "status shows the broker's CURVE"
grep -qF "remote-1     " "$work/status.txt" &&
  grep -q "registered from 127.0.0.1, not started by this grid: up, 3 of 3 slots free, CURVE key" \
    "$work/status.txt" && grep -qF "$(cat "$work/remote-1.pub")" "$work/status.txt"
check $? "status lists the agent the grid did not start, with its address and key"

BIOTGRID_GRID_DIR=$state "$bin" submit "$scene" --mechanism posted --budget 100 \
  --out "$work/job" >"$work/submit.txt" 2>&1
check $? "a job on the CURVE grid succeeded"
"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1
same_energy "$work/job/report.json" "$work/local/report.json"
check $? "its energy equals biotgrid solve's (1e-10 relative)"

kill -TERM $remote
i=0
while kill -0 $remote 2>/dev/null && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
! kill -0 $remote 2>/dev/null; check $? "the remote agent stopped on SIGTERM"
remote=""
before=$(cat "$state/keys/broker.pub")
"$bin" grid down --state "$state" >"$work/down1.txt" 2>&1; check $? "grid down"
"$bin" grid up "$work/curve.json" --state "$state" >"$work/up2.txt" 2>&1
check $? "a second grid up"
[ -n "$before" ] && [ "$(cat "$state/keys/broker.pub")" = "$before" ]; check $? "the second up keeps the grid's keys"
"$bin" grid status --state "$state" >"$work/status2.txt" 2>&1; check $? "and its grid is up"
jq '.security = "none"' "$work/curve.json" >"$work/plain.json"
"$bin" grid up "$work/plain.json" --state "$state" >"$work/up3.txt" 2>&1
[ $? -eq 1 ] && grep -q 'runs with security "curve" where the config says "none"' "$work/up3.txt"
check $? "up with another security on the running grid is refused (got $(cat "$work/up3.txt"))"
"$bin" grid status --state "$state" >"$work/status3.txt" 2>&1
[ $? -eq 0 ] && grep -q "^broker .*, CURVE$" "$work/status3.txt"
check $? "and the CURVE grid still runs as it was"

# Refused before anything starts (exit 2 naming the field).
sed 's/"security": "curve",/"security": "none",/; s|"tcp://127.0.0.1:\*"|"tcp://0.0.0.0:*"|' \
  "$work/curve.json" >"$work/open.json"
"$bin" grid up "$work/open.json" --state "$work/open" >"$work/open.txt" 2>&1
[ $? -eq 2 ] && grep -q "broker.endpoint tcp://0.0.0.0:\* is beyond loopback" "$work/open.txt"
check $? "a grid without keys beyond loopback is refused naming broker.endpoint"
jq 'del(.broker)' "$work/curve.json" >"$work/nobroker.json"
"$bin" grid up "$work/nobroker.json" --state "$work/nobroker" >"$work/nobroker.txt" 2>&1
[ $? -eq 2 ] && grep -q 'security "curve" needs a "broker" object' "$work/nobroker.txt"
check $? "CURVE without a broker is refused"
jq '.security = "tls"' "$work/curve.json" >"$work/badsec.json"
"$bin" grid up "$work/badsec.json" --state "$work/badsec" >"$work/badsec.txt" 2>&1
[ $? -eq 2 ] && grep -q 'security: "curve"' "$work/badsec.txt"
check $? "an unknown security is refused"
[ ! -e "$work/open/grid.json" ] && [ ! -e "$work/nobroker/grid.json" ]
check $? "nothing was started for the refused configs"

grid_test_end "$scripts"
exit $fail
