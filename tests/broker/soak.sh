#!/bin/sh
# soak.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG AUDIT JOBS KILLS [BROKER_KILL]
# The soak benchmark: JOBS jobs of mixed scenes (static, dynamic, morph)
# and mechanisms (central, catallactic, posted) submitted to a local grid
# while KILLS times a random agent is killed with SIGKILL and the grid
# repaired (`grid up` again), and (BROKER_KILL 1, the default) once, half
# way, the broker is killed with SIGKILL and restarted the same way. Every submit carries an
# Idempotency-Key and is retried while the broker is down.
#
# Checked (the smoke in the suite runs a few jobs): no job lost (every
# accepted id is listed once, in a terminal state), none duplicated (one
# job per key, the broker lists no other), the contract log passes the
# simulator's audit. Printed as a Markdown table: jobs by final state,
# the kills, time to the end, broker and agents' memory before and after.
# Run by hand for the full figures: JOBS=100, KILLS=10.
set -u
bin=$1 scripts=$2 work=$3 config=$4 audit=$5 jobs=${6:-100} kills=${7:-10} broker_kill=${8:-1}
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
chaos_pid=
trap '[ -n "$chaos_pid" ] && kill "$chaos_pid" 2>/dev/null; "$bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM
rss() { awk '/^VmRSS/ { print $2 }' "/proc/$1/status" 2>/dev/null || echo 0; }
memory() { # "broker KB, agents KB" of the processes grid.json records
  _b=$(rss "$(jq -r .broker.pid "$state/grid.json")")
  _a=0
  for _p in $(jq -r '.agents[].pid' "$state/grid.json"); do _a=$((_a + $(rss "$_p"))); done
  echo "$_b $_a"
}

"$bin" grid up "$config" --state "$state" --broker-port 0 --broker-endpoint 'tcp://127.0.0.1:*' \
  >"$work/up.txt" 2>&1
check $? "grid up"
grid_token "$state"
url=$(jq -r .broker.url "$state/grid.json")
i=0
while [ "$(market_sellers "$url" service)" != 4 ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
set -- "$root/configs/scenes/bar-twist.json" "$root/tests/fixtures/scenes/short-spin.json" \
  "$root/configs/scenes/stretch-bar.json" "$root/configs/scenes/bar-morph.json"
nscenes=$#
k=0
for s in "$@"; do
  k=$((k + 1))
  cp "$s" "$work/scene-$k.json"
done
mechs="central catallactic posted"
mem_before=$(memory)
t0=$(now)

# The chaos: KILLS agent kills spread over the submissions, the broker's
# at the middle one; each followed by `grid up`, which starts what died.
(
  seed=4242
  r=0
  while [ $r -lt "$kills" ]; do
    sleep 1.5
    r=$((r + 1))
    if [ "$broker_kill" = 1 ] && [ $r -eq $(((kills + 1) / 2)) ]; then
      pid=$(jq -r .broker.pid "$state/grid.json")
      echo "kill broker $pid" >>"$work/kills.txt"
    else
      n=$(jq '.agents | length' "$state/grid.json")
      pick=$(awk -v s=$((seed + r)) -v n="$n" 'BEGIN { srand(s); print int(rand() * n) }')
      pid=$(jq -r ".agents[$pick].pid" "$state/grid.json")
      echo "kill $(jq -r ".agents[$pick].name" "$state/grid.json") $pid" >>"$work/kills.txt"
    fi
    kill -KILL "$pid" 2>/dev/null
    sleep 0.3
    "$bin" grid up "$config" --state "$state" >>"$work/repairs.txt" 2>&1 ||
      echo "repair $r failed" >>"$work/kills.txt"
  done
) &
chaos_pid=$!

: >"$work/ids.txt"
j=1
while [ $j -le "$jobs" ]; do
  s=$(((j - 1) % nscenes + 1))
  m=$(echo $mechs | cut -d' ' -f$(((j - 1) % 3 + 1)))
  jq -n --slurpfile sc "$work/scene-$s.json" --arg m "$m" \
    '{scene: $sc[0], mechanism: $m, budget: 1000}' >"$work/submit.json"
  id= tries=0
  while [ -z "$id" ] && [ $tries -lt 600 ]; do
    id=$(bcurl -sf --max-time 10 -X POST -H 'Content-Type: application/json' \
      -H "Idempotency-Key: soak-$j" --data-binary @"$work/submit.json" "$url/v1/jobs" |
      jq -r '.id // empty')
    [ -n "$id" ] || { sleep 0.1; tries=$((tries + 1)); }
  done
  echo "$j $id $s $m" >>"$work/ids.txt"
  # A resubmit of an accepted key returns the same job (checked at the end).
  [ $((j % 7)) -eq 0 ] && bcurl -sf --max-time 10 -X POST -H 'Content-Type: application/json' \
    -H "Idempotency-Key: soak-$j" --data-binary @"$work/submit.json" "$url/v1/jobs" |
    jq -r '.id // empty' >"$work/again-$j.txt"
  sleep 0.2
  j=$((j + 1))
done
wait "$chaos_pid"
chaos_pid=

# Every job to a terminal state (10 minutes at most for the lot).
deadline=$(($(date +%s) + 600))
while :; do
  bcurl -sf --max-time 10 "$url/v1/jobs?limit=500" >"$work/jobs.json" 2>/dev/null
  left=$(jq '[.jobs[] | select(.state | IN("succeeded", "failed", "cancelled") | not)] | length' \
    "$work/jobs.json" 2>/dev/null || echo x)
  [ "$left" = 0 ] && break
  [ "$(date +%s)" -ge "$deadline" ] && break
  sleep 0.5
done
t1=$(now)
mem_after=$(memory)

accepted=$(awk '$2 != "" { n++ } END { print n + 0 }' "$work/ids.txt")
[ "$accepted" = "$jobs" ]; check $? "every submit was accepted in the end ($accepted of $jobs)"
unique=$(awk '{ print $2 }' "$work/ids.txt" | sort -u | grep -c .)
[ "$unique" = "$jobs" ]; check $? "one job per submit ($unique distinct ids)"
again=0
for f in "$work"/again-*.txt; do
  [ -e "$f" ] || continue
  n=${f##*again-}
  n=${n%.txt}
  [ "$(cat "$f")" = "$(awk -v j="$n" '$1 == j { print $2 }' "$work/ids.txt")" ] || again=1
done
check $again "a resubmit with an accepted key returned the same job"
listed=$(jq '.jobs | length' "$work/jobs.json")
awk '{ print $2 }' "$work/ids.txt" | sort >"$work/ids.sorted"
jq -r '.jobs[].id' "$work/jobs.json" | sort >"$work/listed.sorted"
cmp -s "$work/ids.sorted" "$work/listed.sorted"
check $? "the broker lists exactly the accepted jobs: none lost, none added ($listed listed)"
[ "$left" = 0 ]; check $? "every job ended (still running: $left)"
bcurl -sf "$url/v1/market/contracts.csv" >"$work/contracts.csv"
bcurl -sf "$url/v1/market/agents.csv" >"$work/agents.csv"
"$audit" --live "$work" >"$work/audit.txt" 2>&1
check $? "the contract log passes the simulator's audit ($(tail -1 "$work/audit.txt"))"

succeeded=$(jq '[.jobs[] | select(.state == "succeeded")] | length' "$work/jobs.json")
failed=$(jq '[.jobs[] | select(.state == "failed")] | length' "$work/jobs.json")
set -- $mem_before
bb=$1 ab=$2
set -- $mem_after
ba=$1 aa=$2
echo
echo "| jobs | succeeded | failed | lost | duplicated | agent kills | broker kills | seconds | broker RSS before → after (MB) | agents' RSS before → after (MB) | load |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
printf '| %d | %d | %d | %d | %d | %d | %d | %.1f | %.1f → %.1f | %.1f → %.1f | %s |\n' \
  "$jobs" "$succeeded" "$failed" $((jobs - listed > 0 ? jobs - listed : 0)) $((listed - unique > 0 ? listed - unique : 0)) \
  "$(grep -c '^kill [a-z]*-' "$work/kills.txt")" "$(grep -c '^kill broker' "$work/kills.txt")" \
  "$(echo "$t1 - $t0" | bc)" "$(echo "$bb / 1024" | bc -l)" "$(echo "$ba / 1024" | bc -l)" \
  "$(echo "$ab / 1024" | bc -l)" "$(echo "$aa / 1024" | bc -l)" "$(cut -d' ' -f1-3 /proc/loadavg)"
echo
jq -r '.jobs[] | select(.state == "failed") | .reason' "$work/jobs.json" | sort | uniq -c | sort -rn | head -5
grid_test_end "$scripts"
exit $fail
