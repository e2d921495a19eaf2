#!/bin/sh
# no_agents_left.sh RUNDIR
# Fails if any process started for RUNDIR is alive: a recorded agent PID
# still running that agent (a zombie awaiting its reaper counts as gone:
# it runs nothing; a PID the kernel has since given to another process —
# a suite runs long enough for that — is not the agent: its command line
# does not name the agent's ready file), or any process whose command line
# has "--ready-file RUNDIR/" (found through /proc; the bracket keeps this
# script's own grep from matching).
set -u
dir=$1
# The folder as given and as the kernel resolves it (grid up records its
# state folder's canonical path in the command lines it starts).
canon=$(cd "$dir" 2>/dev/null && pwd -P) || canon=$dir
left=0
for ready in "$dir"/*.ready; do
  [ -e "$ready" ] || continue
  pid=$(cut -d' ' -f2 "$ready")
  state=$(sed 's/.*) //' "/proc/$pid/stat" 2>/dev/null | cut -c1)
  if [ -n "$state" ] && [ "$state" != Z ] &&
    (tr '\0' ' ' <"/proc/$pid/cmdline") 2>/dev/null |
    grep -qF -e "$ready" -e "$canon/$(basename "$ready")"; then
    echo "no_agents_left: agent pid $pid ($ready) is still running" >&2
    left=1
  fi
done
for p in /proc/[0-9]*; do
  if (tr '\0' ' ' <"$p/cmdline") 2>/dev/null | grep -q -e "ready-file[ ]$dir/" -e "ready-file[ ]$canon/"; then
    echo "no_agents_left: ${p#/proc/} still runs: $( (tr "\\0" " " <"$p/cmdline") 2>/dev/null)" >&2
    left=1
  fi
done
[ $left -eq 0 ] && echo "no agent process of $dir is left"
exit $left
