#!/bin/sh
# start_agents.sh BIOTGRID RUNDIR NAME:SERVICES...
# Starts one `biotgrid agent` per NAME on an ephemeral loopback port. Each
# runs under a wrapper subshell that writes its exit status to RUNDIR/NAME.rc
# when it ends; the agent writes "ENDPOINT PID" to RUNDIR/NAME.ready once
# bound. Waits (10 s at most) until every agent is ready; on failure stops
# the ones that started and exits 1. $BG_AGENT_OPTIONS (split on blanks)
# is passed to every agent, e.g. "--broker tcp://127.0.0.1:9".
set -u
bin=$1
dir=$2
shift 2
rm -rf "$dir"
mkdir -p "$dir"
for spec in "$@"; do
  name=${spec%%:*}
  services=${spec#*:}
  # Detached from the test's output pipes, or CTest would wait for them.
  # shellcheck disable=SC2086 # the options are words
  ( "$bin" agent --listen 'tcp://127.0.0.1:*' --services "$services" --slots 4 \
      --name "$name" --ready-file "$dir/$name.ready" ${BG_AGENT_OPTIONS:-} \
      >"$dir/$name.log" 2>&1 </dev/null
    echo $? >"$dir/$name.rc" ) >/dev/null 2>&1 </dev/null &
done
i=0
while [ $i -lt 100 ]; do
  missing=0
  for spec in "$@"; do
    [ -s "$dir/${spec%%:*}.ready" ] || missing=1
  done
  [ $missing -eq 0 ] && break
  sleep 0.1
  i=$((i + 1))
done
if [ $missing -ne 0 ]; then
  echo "start_agents: not every agent became ready within 10 s" >&2
  cat "$dir"/*.log >&2 2>/dev/null
  sh "$(dirname "$0")/stop_agents.sh" "$dir" >/dev/null 2>&1
  exit 1
fi
cat "$dir"/*.ready
