#!/bin/sh
# recover.sh BIOTGRID AGENT_RECOVER RUNDIR SCENE METHOD VICTIM AT [OPTIONS...]
# Starts the agents agent_recover drives (rotation fit a1, a2; sparse solve
# sv; integration step ig; and the spares r3, s2, i2) on ephemeral loopback
# ports in RUNDIR, runs agent_recover against them, then stops every agent
# (the victim's SIGKILL status is expected: only leftovers fail) and checks
# that none is left. INT and TERM stop the agents too; the CTest cleanup
# fixture (stop_agents.sh on RUNDIR) covers a test killed harder.
set -u
bin=$1 prog=$2 dir=$3
shift 3
here=$(dirname "$0")
trap 'sh "$here/stop_agents.sh" "$dir" >/dev/null 2>&1; exit 1' INT TERM
sh "$here/start_agents.sh" "$bin" "$dir" a1:rotfit a2:rotfit sv:solve ig:integ \
  r3:rotfit s2:solve i2:integ >/dev/null || exit 1
"$prog" "$dir" "$@"
rc=$?
sh "$here/stop_agents.sh" "$dir" >"$dir/stop.txt" 2>&1
sh "$here/no_agents_left.sh" "$dir" || rc=1
exit $rc
