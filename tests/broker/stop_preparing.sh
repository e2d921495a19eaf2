#!/bin/sh
# stop_preparing.sh BIOTGRID WORKDIR SCENE
# A broker stopped while a job is being prepared (its mesh built and its
# harmonic start factorized: CHOLMOD and METIS at work, METIS with its own
# SIGTERM handler in place) exits 0 once the preparation step ends, and
# the job is still there after a restart; cancelled while it is prepared
# again, the job ends with a "stopped" event saying so, having bought
# nothing.
set -u
bin=$1 work=$2 scene=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
broker_test_begin "$work"
# A fixed pool (nothing listens on the discard port): the coordinator
# prepares the job at once instead of waiting for a market agent.
broker_config "$work" prep '{"agents": [{"endpoint": "tcp://127.0.0.1:9", "services": "rotfit,solve"}]}'
# 345,600 tetrahedra: preparing takes seconds, well inside the limits.
jq '.mesh.cells = [100, 24, 24] | .name = "big-bar"' "$scene" >"$work/scene.json"
jq -n --slurpfile s "$work/scene.json" '{scene: $s[0], mechanism: "central", budget: 100}' \
  >"$work/submit.json"
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
pid=$(cut -d' ' -f3 "$work/b.ready")
id=$(submit_job "$url" "$work/submit.json")
[ -n "$id" ]; check $? "the big job is accepted ($id)"
i=0
while [ "$(bcurl -sf "$url/v1/jobs/$id" | jq -r .state)" != allocating ] && [ $i -lt 100 ]; do
  sleep 0.1
  i=$((i + 1))
done
sleep 0.5
kill -TERM "$pid"
i=0
while [ ! -s "$work/b.rc" ] && [ $i -lt 600 ]; do sleep 0.1; i=$((i + 1)); done
rc=$(cat "$work/b.rc" 2>/dev/null)
[ "$rc" = 0 ]; check $? "SIGTERM during the preparation: the broker exits 0 (got ${rc:-none} after $((i / 10)) s)"
[ "$rc" = 0 ] || tail -5 "$work/b.log" >&2

start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
st=$(bcurl -sf "$url/v1/jobs/$id" | jq -r .state)
case $st in queued|allocating) r=0 ;; *) r=1 ;; esac
check $r "after the restart the job waits to be prepared again (state $st)"
i=0
while [ "$(bcurl -sf "$url/v1/jobs/$id" | jq -r .state)" != allocating ] && [ $i -lt 100 ]; do
  sleep 0.1
  i=$((i + 1))
done
code=$(bcurl -s -o /dev/null -w '%{http_code}' -X POST "$url/v1/jobs/$id/cancel")
[ "$code" = 200 ]; check $? "cancel while it is prepared (HTTP $code)"
i=0
while ! bcurl -sf --max-time 2 "$url/v1/jobs/$id/events" 2>/dev/null | grep -q '"during":"preparation"' &&
  [ $i -lt 120 ]; do
  sleep 0.5
  i=$((i + 1))
done
bcurl -sf --max-time 2 "$url/v1/jobs/$id/events" >"$work/events.txt" 2>/dev/null
grep -q '^event: stopped' "$work/events.txt" && grep -q '"during":"preparation"' "$work/events.txt"
check $? "its events end with 'stopped' during the preparation"
grep -q '^event: allocation' "$work/events.txt"
[ $? -ne 0 ]; check $? "nothing was bought or run for it"
[ "$(bcurl -sf "$url/v1/jobs/$id" | jq -r .state)" = cancelled ]; check $? "it is cancelled"
stop_broker "$work" b; check $? "the broker stops on SIGTERM with status 0"
exit $fail
