#!/bin/sh
# broker_sigterm.sh BIOTGRID AGENT_SCRIPTS WORKDIR LONG_SCENE SHORT_SCENE MESH_DIR
# SIGTERM on a broker with jobs (issue 27.2): it stops accepting jobs (a
# submit is answered 503 "stopping"), lets a running job finish within its
# stop grace (stop_grace_ms, here GRACE s), and ends every event stream of
# a job still going with a last `end` event; a running job still going at
# the end of the grace stops (a `stopped` event saying the broker stops)
# and is queued again. The broker exits 0 within the grace and a few
# seconds. Restarted on the same store, the queued jobs run and succeed.
#   1. job C (LONG_SCENE, 300 local/global iterations) runs, job D waits (max_jobs 1): SIGTERM; C
#      ends succeeded before the broker exits, D's stream gets `end`.
#   2. job A (LONG_SCENE, local/global, longer than the grace) runs:
#      SIGTERM; A's stream gets `end`, A is queued again; after the
#      restart A and D succeed.
set -u
bin=$1 scripts=$2 work=$3 long=$4 short=$5 mesh_dir=$6
# The grace and the slack on the last stop after it: a sanitizer build
# computes 3-10x slower, so its CTest gives larger ones
# (BG_SIGTERM_GRACE, BG_SIGTERM_SLACK: job C must end within the grace,
# job A outlive it).
GRACE=${BG_SIGTERM_GRACE:-10} SLACK=${BG_SIGTERM_SLACK:-8}
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
fail=0
rm -rf "$work"
mkdir -p "$work"
cleanup() {
  stop_broker "$work" b >/dev/null 2>&1
  sh "$scripts/stop_agents.sh" "$work/agents" >/dev/null 2>&1
}
trap cleanup EXIT
trap 'exit 1' INT TERM HUP
now() { date +%s.%N; }
broker_config "$work" sigterm "{\"max_jobs\": 1, \"stop_grace_ms\": $((GRACE * 1000))}"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
bep=$(cut -d' ' -f2 "$work/b.ready")
# Restarts bind the same port and endpoint, as `grid up` does.
jq --argjson p "${url##*:}" --arg e "$bep" '.port = $p | .endpoint = $e' "$work/broker.json" \
  >"$work/broker2.json" && mv "$work/broker2.json" "$work/broker.json"
BG_AGENT_OPTIONS="--broker $bep --cores 8" sh "$scripts/start_agents.sh" "$bin" "$work/agents" \
  rotfit-1:rotfit rotfit-2:rotfit solve-1:solve integ-1:integ >/dev/null
check $? "four agents start"
i=0
while [ "$(market_sellers "$url" service)" != 4 ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
[ "$(market_sellers "$url" service)" = 4 ]; check $? "they sell on the broker's market"
jq '.solver.method = "local-global" | .solver.max_iterations = 3000' "$long" >"$work/long.json"
# C: a few seconds of local/global, well inside the grace.
jq '.solver.method = "local-global" | .solver.max_iterations = 300' "$long" >"$work/medium.json"
cp "$short" "$work/short.json"
submit() {
  "$bin" submit "$1" --mesh-path "$mesh_dir" --mechanism posted --budget 1000 --broker "$url" \
    --json 2>>"$work/submit.txt" | jq -r .id
}
state_of() { bcurl -sf --max-time 5 "$url/v1/jobs/$1" | jq -r .state; }
wait_state() { # ID STATE SECONDS
  _i=0
  while [ "$(state_of "$1")" != "$2" ] && [ $_i -lt $(($3 * 10)) ]; do
    sleep 0.1
    _i=$((_i + 1))
  done
  [ "$(state_of "$1")" = "$2" ]
}
stream() { # ID FILE: the job's event stream, in the background, into FILE
  bcurl -sN --max-time 120 "$url/v1/jobs/$1/events" >"$2" 2>/dev/null &
}
sigterm() { # → "seconds to exit" once the broker exited, checking a submit is refused meanwhile
  _pid=$(cut -d' ' -f3 "$work/b.ready")
  _t0=$(now)
  kill -TERM "$_pid"
  _code=
  _i=0
  while [ ! -s "$work/b.rc" ] && [ $_i -lt $(((GRACE + SLACK + 2) * 10)) ]; do
    if [ -z "$_code" ] || [ "$_code" = 000 ] || [ "$_code" = 202 ]; then
      _code=$(bcurl -s -o "$work/refused.json" -w '%{http_code}' --max-time 2 -X POST \
        -H 'Content-Type: application/json' --data-binary @"$work/submit-short.json" "$url/v1/jobs")
      # An acceptance before the signal was handled would be a job more:
      # counted at the end.
      [ "$_code" = 202 ] && echo extra >>"$work/extra"
    fi
    sleep 0.1
    _i=$((_i + 1))
  done
  echo "$_code" >"$work/refused.code"
  awk -v a="$_t0" -v b="$(now)" 'BEGIN { printf "%.2f", b - a }'
}
jq -n --slurpfile s "$work/short.json" '{scene: $s[0], mechanism: "posted", budget: 1000}' \
  >"$work/submit-short.json"

# 1. A short job finishes within the grace; a queued one waits.
C=$(submit "$work/medium.json")
wait_state "$C" running 60; check $? "job C runs ($C)"
D=$(submit "$work/short.json")
wait_state "$D" queued 10; check $? "job D waits in queued ($D)"
stream "$D" "$work/d1.events"
sleep 0.3
took=$(sigterm)
[ "$(cat "$work/b.rc" 2>/dev/null)" = 0 ]; check $? "SIGTERM: the broker exits 0 after ${took} s (grace $GRACE s)"
refused_code=$(cat "$work/refused.code")
[ "$refused_code" = 503 ] && jq -e '.type == "/problems/stopping"' "$work/refused.json" >/dev/null
check $? "a submit while it stops is refused 503 stopping (got $refused_code)"
sleep 0.5
grep -q '^event: end' "$work/d1.events" && grep -q '"final":true' "$work/d1.events"
check $? "D's event stream ended with a last end event"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
[ "$(state_of "$C")" = succeeded ]; check $? "C ended succeeded within the grace ($(state_of "$C"))"

# 2. A long job outlives the grace: stopped, queued again, run after the restart.
A=$(submit "$work/long.json")
i=0
while [ $i -lt 600 ]; do
  [ "$(bcurl -sf "$url/v1/jobs/$A" | jq -r '.state == "running" and (.progress.fraction // 0) > 0.05')" = true ] && break
  sleep 0.1
  i=$((i + 1))
done
[ "$(state_of "$A")" = running ]; check $? "job A runs ($A)"
stream "$A" "$work/a.events"
sleep 0.3
took=$(sigterm)
[ "$(cat "$work/b.rc" 2>/dev/null)" = 0 ]; check $? "SIGTERM: the broker exits 0 after ${took} s"
awk -v t="$took" -v g="$GRACE" -v s="$SLACK" 'BEGIN { exit !(t >= g - 0.5 && t <= g + s) }'
check $? "A outlived the grace: the broker waited about $GRACE s for it ($took s)"
sleep 0.5
grep -q '^event: end' "$work/a.events"; check $? "A's event stream ended with a last end event"
grep -q '"broker_stopping":true' "$work/a.events"; check $? "A's stream shows it stopped as the broker stops"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
[ "$(state_of "$A")" != failed ]; check $? "A is not failed after the restart ($(state_of "$A"))"
for j in $A $D; do
  st=$(wait_job "$url" "$j" 120)
  [ "$st" = succeeded ]; check $? "job $j succeeded after the restart (got $st)"
done
n=$(bcurl -sf "$url/v1/jobs?limit=100" | jq '.jobs | length')
[ "$n" = 3 ] && [ ! -s "$work/extra" ]; check $? "3 jobs, none accepted while the broker stopped ($n)"
stop_broker "$work" b; check $? "the broker stops"
sh "$scripts/stop_agents.sh" "$work/agents" >/dev/null
sh "$scripts/no_agents_left.sh" "$work/agents"; check $? "no agent is left"
trap - EXIT
exit $fail
