#!/bin/sh
# solve_kill.sh BIOTGRID RUNDIR SCENE OUTDIR
# Starts its own rotation-fit and sparse-solve agents, runs a long
# local/global solve across them, kills the rotation-fit agent with
# SIGKILL once the solve is under way, and requires exit 1 within the
# agent timeout (2 s) plus a margin, with a message naming the killed
# agent's endpoint and the rotation-fit service. Stops what it started.
set -u
bin=$1 dir=$2 scene=$3 out=$4
here=$(dirname "$0")
sh "$here/start_agents.sh" "$bin" "$dir" k1:rotfit ks:solve >/dev/null || exit 1
ep=$(cut -d' ' -f1 "$dir/k1.ready")
pid=$(cut -d' ' -f2 "$dir/k1.ready")
rc=0
"$bin" solve "$scene" --method local-global --tolerance 1e-15 --max-iterations 1000000 \
  --quiet --agent-timeout 2000 --agents "rotfit=$ep,solve=$(cut -d' ' -f1 "$dir/ks.ready")" \
  --out "$out" >"$dir/solve.log" 2>&1 &
solve=$!
# Under way: the rotation-fit agent has used CPU time (its partition set
# up and fitting), or 5 s at most.
i=0
while [ $i -lt 50 ]; do
  t=$(awk '{print $14 + $15}' "/proc/$pid/stat" 2>/dev/null || echo 0)
  [ "${t:-0}" -gt 5 ] && break
  sleep 0.1
  i=$((i + 1))
done
kill -KILL "$pid"
start=$(date +%s)
wait $solve
status=$?
elapsed=$(( $(date +%s) - start ))
cat "$dir/solve.log"
if [ $status -ne 1 ]; then
  echo "solve_kill: exit status $status, expected 1" >&2; rc=1
fi
if ! grep -q "agent $ep (rotation-fit)" "$dir/solve.log"; then
  echo "solve_kill: the message does not name agent $ep and rotation-fit" >&2; rc=1
fi
if [ $elapsed -gt 10 ]; then
  echo "solve_kill: took $elapsed s after the kill (timeout 2 s)" >&2; rc=1
fi
sh "$here/stop_agents.sh" "$dir" >/dev/null 2>&1
sh "$here/no_agents_left.sh" "$dir" || rc=1
[ $rc -eq 0 ] && echo "solve_kill: exit 1 in ${elapsed} s, naming $ep (rotation-fit)"
exit $rc
