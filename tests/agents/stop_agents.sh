#!/bin/sh
# stop_agents.sh RUNDIR
# SIGTERM to every agent of RUNDIR still running, SIGKILL to one that has
# not exited 10 s later; fails unless every agent exited with status 0 and
# none is left (tests/agents/no_agents_left.sh).
set -u
dir=$1
status=0
for ready in "$dir"/*.ready; do
  [ -e "$ready" ] || { echo "stop_agents: no agents were started in $dir"; exit 0; }
  name=$(basename "$ready" .ready)
  pid=$(cut -d' ' -f2 "$ready")
  [ -e "$dir/$name.rc" ] || kill -TERM "$pid" 2>/dev/null
done
for ready in "$dir"/*.ready; do
  name=$(basename "$ready" .ready)
  pid=$(cut -d' ' -f2 "$ready")
  i=0
  while [ ! -s "$dir/$name.rc" ] && [ $i -lt 100 ]; do
    sleep 0.1
    i=$((i + 1))
  done
  if [ ! -s "$dir/$name.rc" ]; then
    echo "stop_agents: $name (pid $pid) ignored SIGTERM for 10 s: SIGKILL" >&2
    kill -KILL "$pid" 2>/dev/null
    status=1
    sleep 0.2
  else
    rc=$(cat "$dir/$name.rc")
    echo "$name (pid $pid): exit status $rc"
    [ "$rc" = 0 ] || status=1
  fi
done
sh "$(dirname "$0")/no_agents_left.sh" "$dir" || status=1
exit $status
