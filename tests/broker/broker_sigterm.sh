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
GRACE=${BG_SIGTERM_GRACE:-6} SLACK=${BG_SIGTERM_SLACK:-8}
# A's local/global iterations, with a tolerance it never reaches: 2-3 ms
# each on an idle machine, so A runs for several graces at any load (at
# 3,000 it could end inside a 10 s grace on an idle machine).
ITERS=${BG_SIGTERM_ITERS:-6000}
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
broker_agents_test_begin "$work" "$scripts"
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
jq --argjson n "$ITERS" '.solver.method = "local-global" | .solver.tolerance = 1e-300
    | .solver.max_iterations = $n' "$long" >"$work/long.json"
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
sigterm() { # → "seconds to exit" once the broker exited; submits meanwhile
  # Submits go on every 0.1 s until the broker has exited. One sent before
  # the signal is handled may be accepted (202): it is a job like any other
  # (its id goes to $work/extra, and it must run after the restart); once
  # a submit has been refused 503, none may be accepted again.
  _pid=$(cut -d' ' -f3 "$work/b.ready")
  _t0=$(now)
  kill -TERM "$_pid"
  : >"$work/codes"
  _i=0
  while [ ! -s "$work/b.rc" ] && [ $_i -lt $(((GRACE + SLACK + 2) * 10)) ]; do
    _code=$(bcurl -s -o "$work/refused.json" -w '%{http_code}' --max-time 2 -X POST \
      -H 'Content-Type: application/json' --data-binary @"$work/submit-short.json" "$url/v1/jobs")
    echo "$_code" >>"$work/codes"
    [ "$_code" = 503 ] && cp "$work/refused.json" "$work/refused-503.json"
    [ "$_code" = 202 ] && jq -r .id "$work/refused.json" >>"$work/extra"
    sleep 0.1
    _i=$((_i + 1))
  done
  awk -v a="$_t0" -v b="$(now)" 'BEGIN { printf "%.2f", b - a }'
}
refused_while_stopping() { # the codes of one sigterm(): a 503 stopping, no 202 after it
  grep -qx 503 "$work/codes" && jq -e '.type == "/problems/stopping"' "$work/refused-503.json" >/dev/null &&
    ! sed -n '/^503$/,$p' "$work/codes" | grep -qx 202
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
refused_while_stopping
check $? "submits while it stops are refused 503 stopping, none accepted after ($(sort "$work/codes" | uniq -c | tr -s ' \n' ' '))"
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
refused_while_stopping; check $? "submits are refused 503 again, none accepted after"
awk -v t="$took" -v g="$GRACE" -v s="$SLACK" 'BEGIN { exit !(t >= g - 0.5 && t <= g + s) }'
check $? "A outlived the grace: the broker waited about $GRACE s for it ($took s)"
sleep 0.5
grep -q '^event: end' "$work/a.events"; check $? "A's event stream ended with a last end event"
grep -q '"broker_stopping":true' "$work/a.events"; check $? "A's stream shows it stopped as the broker stops"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
[ "$(state_of "$A")" != failed ]; check $? "A is not failed after the restart ($(state_of "$A"))"
# A runs again from its start: its ITERS iterations, at any load.
for j in $A $D $(cat "$work/extra" 2>/dev/null); do
  st=$(wait_job "$url" "$j" 300)
  [ "$st" = succeeded ]; check $? "job $j succeeded after the restart (got $st)"
done
n=$(bcurl -sf "$url/v1/jobs?limit=100" | jq '.jobs | length')
extra=$(cat "$work/extra" 2>/dev/null | wc -l)
[ "$n" = $((3 + extra)) ]; check $? "every accepted job is listed: 3 and $extra accepted before a signal was handled ($n)"
stop_broker "$work" b; check $? "the broker stops"
sh "$scripts/stop_agents.sh" "$work/agents" >/dev/null
sh "$scripts/no_agents_left.sh" "$work/agents"; check $? "no agent is left"
trap - EXIT
exit $fail
