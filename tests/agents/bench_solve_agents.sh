#!/bin/sh
# bench_solve_agents.sh BIOTGRID RUNDIR SCENE OUTDIR [--mesh-path DIR] [--lg-iterations N]
# `biotgrid solve` in process against the same job across agents on
# loopback (RUNDIR's a1, a2 rotation-fit and sv sparse-solve agents, as
# started by start_agents.sh), for Newton and local/global (capped at N
# iterations, default 200): wall seconds per iteration, the ratio to in
# process (measured in this run), bytes per iteration and the agents'
# split (compute / encode / transit / wait) from the per-agent lines.
# The suite runs it on a small scene as a smoke test; the figures quoted
# in the README come from bunny-edit. Exit 1 if a run fails.
set -u
bin=$1 dir=$2 scene=$3 out=$4
shift 4
extra="" lg=200
while [ $# -gt 0 ]; do
  case $1 in
    --mesh-path) extra="--mesh-path $2"; shift 2 ;;
    --lg-iterations) lg=$2; shift 2 ;;
    *) echo "bench_solve_agents: unknown option $1" >&2; exit 2 ;;
  esac
done
ep() { cut -d' ' -f1 "$dir/$1.ready"; }
uptime
run() { # method label agents...
  m=$1 label=$2
  shift 2
  cap=""
  [ "$m" = local-global ] && cap="--max-iterations $lg"
  # shellcheck disable=SC2086
  log=$("$bin" solve "$scene" --method "$m" --quiet $cap $extra --agent-timeout 300000 \
        --out "$out/$m-$label" "$@" 2>&1)
  st=$?
  if [ $st -gt 1 ] || ! printf '%s\n' "$log" | grep -q "^$m: .* iterations"; then
    printf '%s\n' "$log" >&2
    echo "bench_solve_agents: $m $label failed (exit $st)" >&2
    exit 1
  fi
  printf '%s\n' "$log" | awk -v m="$m" -v label="$label" '
    $1 == m":" && / iterations/ {
      for (i = 1; i <= NF; i++) {
        if ($(i+1) ~ /^iterations/) it = $i
        if ($(i+1) == "s") { s = $i; sub(/,$/, "", s) }
      }
    }
    /^  (rotation-fit|sparse-solve) / && / calls/ {
      for (i = 1; i <= NF; i++) {
        if ($(i) == "sent") sent += $(i+1)
        if ($(i) == "received") recv += $(i+1)
        if ($(i) == "compute") comp += $(i+1)
        if ($(i) == "encode") enc += $(i+1)
        if ($(i) == "transit") tr += $(i+1)
        if ($(i) == "wait") wt += $(i+1)
      }
    }
    END {
      printf "%-13s %-18s %5d it  %8.2f ms/it", m, label, it, 1000 * s / it
      if (sent + recv > 0)
        printf "  %9.0f B/it  agents: compute %.2f, encode %.2f, transit %.2f, wait %.2f ms/it", \
               (sent + recv) / it, 1000 * comp / it, 1000 * enc / it, 1000 * tr / it, 1000 * wt / it
      printf "\n"
    }'
}
for m in newton local-global; do
  run $m in-process
  run $m "1 rotfit + solve" --agents "rotfit=$(ep a1),solve=$(ep sv)"
  run $m "2 rotfit + solve" --agents "rotfit=$(ep a1),rotfit=$(ep a2),solve=$(ep sv)"
done
uptime
