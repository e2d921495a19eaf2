#!/bin/sh
# curve.sh BIOTGRID WORKDIR SCENE
# CURVE between the broker and its agents, on loopback: `biotgrid keygen`
# (modes, never overwriting); bad keys and options refused with exit 2
# naming them (a broker or agent beyond loopback without keys, one key
# without the other, a secret key others may read, a secret key given as
# a public one, a bad key file in the allowlist); then a CURVE broker with
# two agents computes a job with `biotgrid solve`'s energy, /v1/agents
# shows each agent's address and key; an unknown key, a plaintext agent,
# an agent claiming another's name with its own key and a second agent
# with a registered agent's key are refused, each logged with the peer's
# address (and key) on the broker and told on the agent; a plaintext client
# is refused by an agent's own socket; a key added to the allowlist gets
# its agent in without a restart; every process stops on SIGTERM (a
# refused agent included) and none is left.
set -u
bin=$1 work=$2 scene=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
rm -rf "$work"
mkdir -p "$work/keys" "$work/auth" "$work/bad-auth"
fail=0
pids=""

# Starts an agent in the background, its output to WORK/NAME.log.
agent() {
  _name=$1
  shift
  "$bin" agent "$@" >"$work/$_name.log" 2>&1 </dev/null &
  pids="$pids $!"
  eval "pid_$_name=$!"
}

# SIGTERM to every agent started, each must be gone within 10 s.
stop_agents() {
  for _p in $pids; do kill -TERM "$_p" 2>/dev/null; done
  _left=""
  for _p in $pids; do
    _i=0
    while kill -0 "$_p" 2>/dev/null && [ $_i -lt 100 ]; do sleep 0.1; _i=$((_i + 1)); done
    if kill -0 "$_p" 2>/dev/null; then
      _left="$_left $_p"
      kill -KILL "$_p" 2>/dev/null
    fi
  done
  pids=""
  [ -z "$_left" ]
}
trap 'stop_agents; stop_broker "$work" broker; exit 1' INT TERM

# Waits up to $2 seconds for file $1 to hold the fixed string $3.
wait_for() {
  _i=0
  while ! grep -qF -- "$3" "$1" 2>/dev/null && [ $_i -lt $(($2 * 10)) ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  grep -qF -- "$3" "$1" 2>/dev/null
}

# Expects exit status 2 and a message holding $1 from the command after it.
refused() {
  _want=$1
  shift
  "$@" >"$work/out.txt" 2>"$work/err.txt" </dev/null
  _rc=$?
  [ $_rc -eq 2 ] && grep -qF -- "$_want" "$work/err.txt"
  _ok=$?
  [ $_ok -eq 0 ] || { echo "  got exit $_rc: $(cat "$work/err.txt")" >&2; }
  return $_ok
}

# ---------------------------------------------------------------- keygen
k=$work/keys
"$bin" keygen "$k/broker" >"$work/keygen.txt" 2>&1
check $? "keygen writes a key pair"
[ "$(stat -c %a "$k/broker.key")" = 600 ] && [ "$(stat -c %a "$k/broker.pub")" = 644 ]
check $? "the secret key is mode 0600, the public key 0644"
grep -qF -- "$(cat "$k/broker.pub")" "$work/keygen.txt"
check $? "keygen prints the public key"
before=$(cat "$k/broker.key")
refused "broker.key exists: a key is never overwritten" "$bin" keygen "$k/broker"
check $? "keygen refuses to overwrite a key (exit 2)"
[ "$(cat "$k/broker.key")" = "$before" ]; check $? "the key is unchanged"
refused "nowhere: No such file or directory" "$bin" keygen "$work/nowhere/x"
check $? "keygen into a missing folder: exit 2 naming it"
for n in rot1 rot2 rogue; do "$bin" keygen "$k/$n" >/dev/null || fail=1; done
cp "$k/rot1.pub" "$k/rot2.pub" "$work/auth/"

# ------------------------------------------------- bad input, named (exit 2)
refused "--curve-key: the agents' endpoint tcp://0.0.0.0:* is beyond loopback" \
  "$bin" broker --port 0 --endpoint 'tcp://0.0.0.0:*' --state-dir "$work/st0"
check $? "a broker beyond loopback without a key is refused naming --curve-key"
refused "--curve-key needs --authorized-agents" \
  "$bin" broker --port 0 --endpoint 'tcp://127.0.0.1:*' --state-dir "$work/st0" \
  --curve-key "$k/broker.key"
check $? "--curve-key without --authorized-agents is refused"
cp "$k/broker.key" "$work/open.key" && chmod 644 "$work/open.key"
refused "chmod 600" "$bin" broker --port 0 --endpoint 'tcp://127.0.0.1:*' \
  --state-dir "$work/st0" --curve-key "$work/open.key" --authorized-agents "$work/auth"
check $? "a secret key others may read is refused"
echo "not a key" >"$work/bad-auth/bad.pub"
refused "bad.pub:1: not a CURVE key" "$bin" broker --port 0 --endpoint 'tcp://127.0.0.1:*' \
  --state-dir "$work/st0" --curve-key "$k/broker.key" --authorized-agents "$work/bad-auth"
check $? "a bad key file in the allowlist is refused naming its line"
refused "--curve-key: tcp://0.0.0.0:* is beyond loopback" \
  "$bin" agent --listen 'tcp://0.0.0.0:*'
check $? "an agent listening beyond loopback without a key is refused"
refused "--curve-key needs --broker-key" "$bin" agent --curve-key "$k/rot1.key"
check $? "--curve-key without --broker-key is refused"
refused "is a secret key file" "$bin" agent --curve-key "$k/rot1.key" --broker-key "$k/broker.key"
check $? "a secret key given as the broker's public key is refused"
[ ! -e "$work/st0/broker.sqlite" ]; check $? "no refused broker made a store"

# ------------------------------------------------ a CURVE broker and agents
jq -n --arg s "$work/st" --arg key "$k/broker.key" --arg auth "$work/auth" \
  '{name: "curve", port: 0, endpoint: "tcp://127.0.0.1:*", state_dir: $s, curve_key: $key,
    authorized_agents: $auth}' >"$work/broker.json"
start_broker "$bin" "$work" broker "$work/broker.json"
check $? "the CURVE broker starts"
grep -qF "agents: CURVE, public key $(cat "$k/broker.pub"), 2 authorized" "$work/broker.log"
check $? "the broker says it speaks CURVE with its public key and 2 authorized keys"
url=$(cut -d' ' -f1 "$work/broker.ready") ep=$(cut -d' ' -f2 "$work/broker.ready")
kb=$k/broker.pub
agent rot1 --broker "$ep" --curve-key "$k/rot1.key" --broker-key "$kb" --services rotfit,solve \
  --slots 2 --cores 4 --memory 16
agent rot2 --broker "$ep" --curve-key "$k/rot2.key" --broker-key "$kb" --services rotfit,integ \
  --slots 2 --cores 4 --memory 16
n=$(agents_matching "$url" '.alive and (.services | length) > 0' 2 100)
bcurl -sf "$url/v1/agents" >"$work/agents.json"
for n in rot1 rot2; do
  jq -e --arg n $n --arg key "$(cat "$k/$n.pub")" \
    '[.agents[] | select(.name == $n and .key == $key and .address == "127.0.0.1" and .alive)] | length >= 1' \
    "$work/agents.json" >/dev/null
  check $? "/v1/agents shows $n alive with its address and its key"
done

jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 100}' >"$work/submit.json"
id=$(submit_job "$url" "$work/submit.json")
st=$(wait_job "$url" "$id" 300)
[ "$st" = succeeded ]; check $? "a job over CURVE succeeded (got $st)"
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"
"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1
same_energy "$work/report.json" "$work/local/report.json"
check $? "its energy equals biotgrid solve's (1e-10 relative)"
used=$(jq '[.agents[] | select(.calls > 0) | .endpoint] | unique | length' "$work/report.json")
[ "$used" -eq 2 ]; check $? "it computed on both agents (got $used)"

# --------------------------------------------------------------- refusals
agent rogue --broker "$ep" --curve-key "$k/rogue.key" --broker-key "$kb" --services rotfit \
  --slots 1 --cores 0
wait_for "$work/broker.log" 10 "refused 127.0.0.1: CURVE key $(cat "$k/rogue.pub") is not among the authorized agents' keys"
check $? "the broker logs the unknown key with its address and key"
wait_for "$work/rogue.log" 10 "refused this process's CURVE key (ZAP status 400)"
check $? "the agent with the unknown key is told"
agent plain --broker "$ep" --name plain --services rotfit --slots 1 --cores 0
wait_for "$work/broker.log" 15 "(no key shown)"
check $? "the broker logs the plaintext agent's refusal"
agent thief --broker "$ep" --curve-key "$k/rot2.key" --broker-key "$kb" --name rot1 \
  --services rotfit --slots 1 --cores 0
wait_for "$work/broker.log" 10 "refused the registration of agent 'rot1' from 127.0.0.1 (CURVE key $(cat "$k/rot2.pub"), authorized as 'rot2'): the name 'rot1' is not its key's"
check $? "another key claiming rot1's name is refused, logged with address and key"
wait_for "$work/thief.log" 10 "the broker says: registration refused: the name 'rot1' is not its key's"
check $? "the agent claiming the name is told"
agent twin --broker "$ep" --curve-key "$k/rot1.key" --broker-key "$kb" --services rotfit \
  --slots 1 --cores 0
wait_for "$work/broker.log" 10 "the name 'rot1' is registered by another agent (at 127.0.0.1)"
check $? "a second agent with rot1's key cannot take its registered name"
bcurl -sf "$url/v1/agents" | jq -r '[.agents[].name] | unique | join(",")' >"$work/names.txt"
[ "$(cat "$work/names.txt")" = "rot1,rot2" ]
check $? "the broker lists only rot1 and rot2 (got $(cat "$work/names.txt"))"
rot1_ep=$(jq -r '.agents[] | select(.name == "rot1" and (.services | length) > 0) | .endpoint' \
  "$work/agents.json")
"$bin" solve "$scene" --agents "rotfit=$rot1_ep,solve=$rot1_ep" --agent-timeout 1000 \
  --quiet --out "$work/plain-solve" >"$work/plain-solve.txt" 2>&1
# Refused in its handshake, the client's DEALER either queued the request
# on a connection that then closed (no reply) or had none to queue it on
# while libzmq reconnects (the send times out): no answer either way.
rc=$?
[ $rc -eq 1 ] && grep -Eq "no reply to .* within 1000 ms|send failed: no connection took the message" \
  "$work/plain-solve.txt"
check $? "a plaintext client gets no answer from a CURVE agent (got $rc: $(tail -1 "$work/plain-solve.txt"))"
wait_for "$work/rot1.log" 10 "compute endpoint: refused"
check $? "the agent's own socket logs the plaintext client's refusal"

# A key added to the allowlist: its agent gets in, the broker not restarted.
cp "$k/rogue.pub" "$work/auth/"
i=0
while [ $i -lt 250 ]; do
  bcurl -sf "$url/v1/agents" | jq -e '[.agents[] | select(.name == "rogue" and .alive)] | length > 0' \
    >/dev/null && break
  sleep 0.1
  i=$((i + 1))
done
[ $i -lt 250 ]; check $? "rogue's key added to the folder: it registers without a restart ($((i / 10)) s)"

stop_agents; check $? "every agent stopped on SIGTERM within 10 s, the refused ones too"
stop_broker "$work" broker; check $? "the broker stopped on SIGTERM and exited 0"
for p in $pid_rot1 $pid_rot2 $pid_rogue $pid_plain $pid_thief $pid_twin; do
  ! kill -0 "$p" 2>/dev/null || { echo "FAIL: pid $p still runs" >&2; fail=1; }
done
exit $fail
