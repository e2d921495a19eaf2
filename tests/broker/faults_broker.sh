#!/bin/sh
# faults_broker.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG LONG_SCENE SHORT_SCENE AUDIT MESH_DIR
# The broker killed (SIGKILL) during a job, on a local grid (GRID_CONFIG,
# one sparse-solve agent with one slot: its jobs run one at a time, and
# while the dead broker's contract held that slot no job could run), then `grid up`
# again, which starts a broker on the same endpoint and port with the same
# store (issue 27.2):
#   - before the kill: job A (LONG_SCENE, local/global) runs, jobs B, C
#     and D (SHORT_SCENE) wait for the sparse solve in allocating, job E
#     waits in queued (the broker takes 4 jobs at a time);
#   - the agents hear the new broker's epoch when they register again and
#     drop the dead broker's contracts and job state at once, each saying
#     so in its log: nothing waits for the 600 s leases;
#   - every job ends succeeded; A ran once more, from its start (one
#     "restarted" event, running twice in all, once per broker), the others
#     ran once; A's energy is `biotgrid solve`'s (1e-9 relative);
#   - a new job F submitted after the restart runs and succeeds;
#   - the new broker's contract log passes the live audit (no service
#     request bought twice);
# and prints the time from the restart (`grid up`) to the first job
# running again, and from F's submission to F running.
set -u
bin=$1 scripts=$2 work=$3 config=$4 long=$5 short=$6 audit=$7 mesh_dir=$8
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
trap '"$bin" grid down --state "$state" >/dev/null 2>&1' EXIT
jobs_states() { bcurl -sf --max-time 5 "$url/v1/jobs?limit=100" | jq -r '[.jobs[].state] | join(",")'; }
state_of() { bcurl -sf --max-time 5 "$url/v1/jobs/$1" | jq -r .state; }
submit() { # SCENE → id
  "$bin" submit "$1" --mesh-path "$mesh_dir" --mechanism posted --budget 1000 --broker "$url" \
    --json 2>>"$work/submit.txt" | jq -r .id
}
grid_up_market "$bin" "$config" "$state"
# BG_FAULT_LG_ITERS local/global iterations (3,000 by default; fewer on
# the small scene the sanitizer build uses), all of them: a tolerance no
# run reaches, so the job lasts as long on every scene and machine load.
jq --argjson n "${BG_FAULT_LG_ITERS:-3000}" '.solver.method = "local-global" | .solver.max_iterations = $n
  | .solver.tolerance = 1e-300' "$long" >"$work/long.json"
cp "$short" "$work/short.json"
"$bin" solve "$work/long.json" --mesh-path "$mesh_dir" --quiet --out "$work/local" \
  >"$work/local.txt" 2>&1
[ $? -le 1 ] && [ -s "$work/local/report.json" ]; check $? "biotgrid solve (A's reference)"

A=$(submit "$work/long.json")
i=0 st=none
while [ $i -lt 600 ]; do
  st=$(bcurl -sf "$url/v1/jobs/$A" | jq -r 'if .state == "running" and (.progress.fraction // 0) > 0.05
                                            then "progressing" else .state end')
  case $st in progressing|succeeded|failed|cancelled) break ;; esac
  sleep 0.1
  i=$((i + 1))
done
[ "$st" = progressing ]; check $? "job A runs ($A, $st)"
B=$(submit "$work/short.json") C=$(submit "$work/short.json") D=$(submit "$work/short.json")
E=$(submit "$work/short.json")
echo "$A $B $C $D $E" | tr ' ' '\n' >"$work/ids"
[ "$(grep -c '^j' "$work/ids")" -eq 5 ]; check $? "jobs B, C, D, E accepted ($B $C $D $E)"
i=0
while [ "$(state_of "$E")" != queued ] || [ "$(state_of "$D")" != allocating ]; do
  [ $i -lt 100 ] || break
  sleep 0.1
  i=$((i + 1))
done
before=$(for j in $A $B $C $D $E; do state_of "$j"; done | tr '\n' ,)
[ "$before" = running,allocating,allocating,allocating,queued, ]
check $? "at the kill: A running, B C D allocating, E queued ($before)"

pid=$(jq -r .broker.pid "$state/grid.json")
kill -KILL "$pid"
i=0
while [ -d "/proc/$pid" ] && [ "$(sed 's/.*) //' "/proc/$pid/stat" 2>/dev/null | cut -c1)" != Z ] &&
  [ $i -lt 50 ]; do
  sleep 0.1
  i=$((i + 1))
done
echo "killed the broker (pid $pid) with SIGKILL"
t_up=$(now)
"$bin" grid up "$config" --state "$state" >"$work/up2.txt" 2>&1
check $? "grid up again restarts the broker ($(tr '\n' ' ' <"$work/up2.txt"))"
t_upped=$(now)
url2=$(jq -r .broker.url "$state/grid.json")
[ "$url2" = "$url" ]; check $? "on the same port ($url2)"
grid_token "$state"
t_run=
i=0
while [ $i -lt 600 ]; do
  case ",$(jobs_states)," in
    *,running,*) t_run=$(now); break ;;
  esac
  sleep 0.05
  i=$((i + 1))
done
[ -n "$t_run" ]; check $? "a job runs again after the restart"
if [ -z "$t_run" ]; then
  echo "no job runs 30 s after the restart: the agents still hold the dead broker's contracts" >&2
  exit 1
fi
[ -n "$t_run" ] && awk -v a="$t_up" -v b="$t_upped" -v c="$t_run" 'BEGIN {
  printf "broker restart: grid up took %.2f s; restart -> first job running %.2f s\n", b - a, c - a }'
F=$(submit "$work/short.json")
t_f=$(now)
[ -n "$F" ] && [ "$F" != null ]; check $? "a new job F is accepted after the restart ($F)"
i=0 t_frun=
while [ $i -lt 1200 ]; do
  case $(state_of "$F") in running|succeeded) t_frun=$(now); break ;; failed|cancelled) break ;; esac
  sleep 0.1
  i=$((i + 1))
done
[ -n "$t_frun" ] && awk -v a="$t_f" -v b="$t_frun" 'BEGIN {
  printf "new job F: submitted -> running %.2f s\n", b - a }'
for j in $A $B $C $D $E $F; do
  st=$(wait_job "$url" "$j" 300)
  [ "$st" = succeeded ]; check $? "job $j succeeded (got $st)"
done
# Each agent heard the new epoch and dropped the dead broker's deals.
n=0 total=0
for log in "$state"/*.log; do
  case $log in */broker.log) continue ;; esac
  total=$((total + 1))
  grep -q "the broker restarted (epoch" "$log" && n=$((n + 1))
done
[ "$total" -ge 1 ] && [ $n -eq "$total" ]
check $? "every agent dropped the dead broker's contracts and jobs on its new epoch ($n of $total)"
runs() { # ID → times it entered running
  bcurl -sf --max-time 10 "$url/v1/jobs/$1/events" |
    awk '/^event: / { e = $2 } /^data: / && e == "state" && /"running"/ { n++ } END { print n + 0 }'
}
restarted() {
  bcurl -sf --max-time 10 "$url/v1/jobs/$1/events" | grep -c '^event: restarted'
}
[ "$(runs "$A")" = 2 ] && [ "$(restarted "$A")" = 1 ]
check $? "A ran again once, from its start (running $(runs "$A") times, $(restarted "$A") restarted event)"
once=0
for j in $B $C $D $E $F; do
  [ "$(runs "$j")" = 1 ] && [ "$(restarted "$j")" = 0 ] && once=$((once + 1))
done
[ $once -eq 5 ]; check $? "B, C, D, E, F ran once each ($once of 5)"
bcurl -sf "$url/v1/jobs/$A/result/report.json" >"$work/report.json"
jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" \
  '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-9 * ($b[0].runs[0].energy | fabs)' |
  grep -q true
check $? "A's energy equals biotgrid solve's to 1e-9"
n=$(bcurl -sf "$url/v1/jobs?limit=100" | jq '.jobs | length')
[ "$n" = 6 ]; check $? "the broker lists the 6 jobs and no other ($n)"
bcurl -sf "$url/v1/market/contracts.csv" >"$work/contracts.csv"
bcurl -sf "$url/v1/market/agents.csv" >"$work/agents.csv"
"$audit" --live "$work" >"$work/audit.txt" 2>&1
check $? "the new broker's contract log passes the live audit ($(cat "$work/audit.txt"))"
grid_test_end "$scripts"
trap - EXIT
exit $fail
