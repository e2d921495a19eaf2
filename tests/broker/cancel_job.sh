#!/bin/sh
# cancel_job.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG LONG_SCENE SHORT_SCENE
# Cancel interrupts a running solve: on a local grid (`grid up`, ephemeral
# loopback ports) LONG_SCENE runs with 100,000 steps (hours of work); once
# it runs and has reported progress, holding agents' slots, POST
# /v1/jobs/{id}/cancel answers with the job cancelled, the solve stops
# (the job's "stopped" event) and every agent's slots are free again in
# /v1/agents within 20 s; the job has no result and no "solved" event, and
# its progress no longer moves. SHORT_SCENE then succeeds on the same
# agents. Before the cancel a second long job is submitted: the first holds
# the host's 2 cores (layer 1; the grid says it sells 2), so it waits in allocating, its allocation
# event says it asks again and why, and it runs once the first is
# cancelled; it is cancelled in turn. `grid down` leaves no process.
set -u
bin=$1 scripts=$2 work=$3 config=$4 long=$5 short=$6
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
# The grid's host sells 2 cores: a job of this grid holds both (its widest
# phase: the rotation fit's two parts, or the sparse solve's two cores), so
# the second job below waits for the first whatever the machine has.
jq '.host = {cores: 2}' "$config" >"$work/grid-config.json"
grid_up_market "$bin" "$work/grid-config.json" "$state"
idle() { market_sellers "$url" idle; }
# progressing ID SECONDS: polls until job ID runs and has reported progress.
progressing() {
  _i=0 _st=none
  while [ $_i -lt $(($2 * 10)) ]; do
    _st=$(bcurl -sf "$url/v1/jobs/$1" | jq -r 'if .state == "running" and .progress != null
                                              then "progressing" else .state end')
    case $_st in progressing|succeeded|failed|cancelled) break ;; esac
    sleep 0.1
    _i=$((_i + 1))
  done
  echo "$_st"
}

jq -n --slurpfile s "$long" '{scene: ($s[0] | .task.steps = 100000), mechanism: "central", budget: 100}' \
  >"$work/long.json"
id=$(bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$work/long.json" \
  "$url/v1/jobs" | jq -r .id)
[ -n "$id" ]; check $? "the long job is accepted ($id)"
st=$(progressing "$id" 120)
[ "$st" = progressing ]; check $? "the long job runs and reports progress (got $st)"
busy=$((nagents - $(idle)))
[ "$busy" -ge 2 ]; check $? "it holds slots on $busy agents"

id_b=$(bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$work/long.json" \
  "$url/v1/jobs" | jq -r .id)
i=0 said=null
while [ $i -lt 300 ]; do
  said=$(bcurl -sf "$url/v1/jobs/$id_b" | jq -c '[.state, .allocation.retry, .allocation.reason]')
  case $said in '["allocating",'[0-9]*) break ;; esac
  sleep 0.1
  i=$((i + 1))
done
echo "$said" | grep -Eq '^\["allocating",[0-9]+,"(no seller|timeout)"\]$'
check $? "a second long job waits while the first holds the cores it needs, and says why ($said)"
# It asks again with backoff (0.1 s doubling to 2 s): some 5 times in 4 s,
# where a loop without pauses asks thousands of times.
sleep 4

code=$(bcurl -s -o "$work/cancel.json" -w '%{http_code}' -X POST "$url/v1/jobs/$id/cancel")
case $code in 200|202) r=0 ;; *) r=1 ;; esac
check $r "POST /v1/jobs/{id}/cancel answers $code"
jq -e '.state == "cancelled"' "$work/cancel.json" >/dev/null; check $? "the answer shows the job cancelled"
st=$(progressing "$id_b" 60)
[ "$st" = progressing ]; check $? "the waiting job runs once the first is cancelled (got $st)"
bcurl -sf "$url/v1/jobs/$id_b/events" --max-time 2 >"$work/events_b.txt" 2>/dev/null
retries=$(grep -c '"retry":' "$work/events_b.txt")
[ "$retries" -ge 2 ] && [ "$retries" -le 12 ]
check $? "it asked again $retries times in the 4 s it waited, with backoff (2 to 12)"
t0=$(now)
code=$(bcurl -s -o /dev/null -w '%{http_code}' -X POST "$url/v1/jobs/$id_b/cancel")
case $code in 200|202) r=0 ;; *) r=1 ;; esac
check $r "the second long job is cancelled too ($code)"
i=0
while [ $i -lt 200 ]; do
  [ "$(idle)" -eq "$nagents" ] && break
  sleep 0.1
  i=$((i + 1))
done
freed=$(awk -v a="$t0" -v b="$(now)" 'BEGIN { printf "%.2f", b - a }')
[ "$(idle)" -eq "$nagents" ]; check $? "every agent's slots are free again ${freed} s after the cancel"
bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events.txt"
grep -q '^event: stopped' "$work/events.txt"; check $? "the job's events record that its solve stopped"
! grep -q '^event: solved' "$work/events.txt"; check $? "and no solved event"
p1=$(bcurl -sf "$url/v1/jobs/$id" | jq -c '[.state, .progress.iteration]')
sleep 1
p2=$(bcurl -sf "$url/v1/jobs/$id" | jq -c '[.state, .progress.iteration]')
[ "$p1" = "$p2" ] && echo "$p1" | grep -q '^\["cancelled",'
check $? "the job stays cancelled and its progress no longer moves ($p1, then $p2)"
code=$(bcurl -s -o /dev/null -w '%{http_code}' "$url/v1/jobs/$id/result/report.json")
[ "$code" != 200 ]; check $? "the cancelled job has no report.json (HTTP $code)"

jq -n --slurpfile s "$short" '{scene: $s[0], mechanism: "posted", budget: 100}' >"$work/short.json"
id2=$(bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$work/short.json" \
  "$url/v1/jobs" | jq -r .id)
st=$(wait_job "$url" "$id2" 300)
[ "$st" = succeeded ]; check $? "a job after the cancel runs on the same agents (got $st)"

grid_test_end "$scripts"
exit $fail
