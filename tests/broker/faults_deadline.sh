#!/bin/sh
# faults_deadline.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE MESH_DIR
# A lost agent with no seller to replace it: on a local grid with one
# sparse-solve agent (GRID_CONFIG), SCENE runs local/global (400
# iterations) with a deadline of DEADLINE s after submission; its
# sparse-solve agent is killed once it runs. The job keeps asking the
# market ("rebuy" events: no seller, with backoff) until its deadline, and
# only then fails, its reason naming the lost agent, the service and the
# deadline; it fails no earlier than the deadline and within 15 s after it.
# `grid down` leaves no process.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5 mesh_dir=$6
deadline=25
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
events_of() { awk -v k="$2" '/^event: / { e = $2 } /^data: / && e == k { sub(/^data: /, ""); print }' "$1"; }
grid_up_market "$bin" "$config" "$state"
jq '.solver.method = "local-global" | .solver.max_iterations = 400' "$scene" >"$work/scene.json"
t_submit=$(now)
id=$("$bin" submit "$work/scene.json" --mesh-path "$mesh_dir" --deadline $deadline \
  --broker "$url" --json 2>"$work/submit.txt" | jq -r .id)
[ -n "$id" ] && [ "$id" != null ]; check $? "the job is accepted with a deadline of $deadline s ($id)"
bcurl -sf "$url/v1/jobs/$id" | jq -e --argjson d $deadline '.deadline == $d' >/dev/null
check $? "GET /v1/jobs/{id} shows its deadline"
i=0 st=none
while [ $i -lt 300 ]; do
  doc=$(bcurl -sf "$url/v1/jobs/$id")
  st=$(echo "$doc" | jq -r 'if .state == "running" and .progress != null then "progressing" else .state end')
  case $st in progressing|succeeded|failed|cancelled) break ;; esac
  sleep 0.1
  i=$((i + 1))
done
[ "$st" = progressing ]; check $? "the job runs (got $st)"
victim=$(echo "$doc" | jq -r '[.contracts[] | select(.service == "sparse-solve")][0].agent')
pid=$(jq -r --arg n "$victim" '.agents[] | select(.name == $n) | .pid' "$state/grid.json")
kill -KILL "$pid"
echo "killed $victim (pid $pid), the grid's only sparse-solve agent"
st=$(wait_job "$url" "$id" 120)
t_end=$(now)
[ "$st" = failed ]; check $? "with no seller to replace it the job fails (got $st)"
reason=$(bcurl -sf "$url/v1/jobs/$id" | jq -r .reason)
case $reason in
  *"$victim"*sparse-solve*"no seller could be found before the job's deadline"*) r=0 ;;
  *) r=1 ;;
esac
check $r "its reason names $victim, the service and the deadline ($reason)"
awk -v s="$t_submit" -v e="$t_end" -v d=$deadline 'BEGIN {
  printf "failed %.1f s after submission (deadline %d s)\n", e - s, d; exit !(e - s >= d && e - s <= d + 15) }'
check $? "it failed at its deadline, not before"
bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events.txt"
events_of "$work/events.txt" agent_lost | jq -e --arg v "$victim" '.agent == $v' >/dev/null
check $? "an agent_lost event names $victim"
n=$(events_of "$work/events.txt" rebuy | jq -s '[.[] | select(.reason == "no seller" and .retry != null)] | length')
[ "$n" -ge 3 ]; check $? "it asked the market again $n times (no seller), with backoff"
events_of "$work/events.txt" rebuy | jq -s -e 'last | .failed == true' >/dev/null
check $? "the last rebuy event says it gave up"
grid_test_end "$scripts"
exit $fail
