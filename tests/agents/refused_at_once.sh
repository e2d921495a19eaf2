#!/bin/sh
# refused_at_once.sh BIOTGRID RUNDIR SCENE OUTDIR
# An agent that sells on a market computes only for jobs it holds a
# contract for. `biotgrid solve --agents` on such agents (started with
# --broker, here an endpoint no broker listens on, so no contract can ever
# exist) must fail at once with the agent's own refusal, not after its
# --agent-timeout with "no reply": the refusal quotes the request's
# sequence number, so the client matches it. Exit 1, the message naming
# the contract, well within the 8 s timeout given. Every agent is stopped
# and none is left.
set -u
bin=$1 dir=$2 scene=$3 out=$4
here=$(dirname "$0")
fail=0
BG_AGENT_OPTIONS="--broker tcp://127.0.0.1:9 --cores 0" \
    sh "$here/start_agents.sh" "$bin" "$dir" rf:rotfit sv:solve >/dev/null || exit 1
ep() { cut -d' ' -f1 "$dir/$1.ready"; }
t0=$(date +%s.%N)
log=$("$bin" solve "$scene" --quiet --agent-timeout 8000 \
      --agents "rotfit=$(ep rf),solve=$(ep sv)" --out "$out" 2>&1)
status=$?
seconds=$(echo "$(date +%s.%N) - $t0" | bc)
printf '%s\n' "$log"
echo "solve exited $status after $seconds s"
[ "$status" -eq 1 ] || { echo "FAIL: exit status $status, expected 1"; fail=1; }
printf '%s\n' "$log" | grep -q "refused: no such job (frame 0, job): agent holds no contract for job" ||
    { echo "FAIL: the agent's refusal is not shown"; fail=1; }
printf '%s\n' "$log" | grep -q "no reply to" && { echo "FAIL: the client waited for a reply"; fail=1; }
[ "$(echo "$seconds < 4" | bc)" = 1 ] || { echo "FAIL: took $seconds s (timeout 8 s)"; fail=1; }
sh "$here/stop_agents.sh" "$dir" || fail=1
exit $fail
