#!/bin/sh
# bench_curve.sh BIOTGRID SCENE [MESH] [WORKDIR] [ROUNDS]
# What CURVE costs a job through a local grid: the shipped grid
# (configs/grids/local.json: 4 agents and the broker, ephemeral loopback
# ports, the agents selling on the live market) brought up without keys
# and with "security": "curve", alternately, ROUNDS times each (default 2),
# in one run, in the order none-curve, curve-none, ... so a drift in the
# machine's load falls on both alike; each round submits SCENE (with MESH
# uploaded beside it when given) and times submit → succeeded (polled every
# 50 ms). Prints the machine (cores) and its load before and after, every
# round's wall time, the solve's own wall time from the report and the
# agents' transit time (the report's transit_seconds summed over its
# agents), each mode's mean and best, the ratio CURVE / plaintext, and
# checks every job succeeded with the first round's energy (1e-10
# relative). Every grid it brings up is brought down on any exit.
# Run by hand for the figures (README, "Benchmarks"); the suite runs it
# on bar-twist, one round each, as broker.bench_curve.smoke: it asserts
# correctness, no speed.
set -u
bin=$1 scene=$2 mesh=${3:-} work=${4:-/tmp/bench-curve} rounds=${5:-2}
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$work"
mkdir -p "$work"
state=""
down() { [ -n "$state" ] && "$bin" grid down --state "$state" >/dev/null 2>&1; state=""; }
trap 'down' EXIT
trap 'exit 1' INT TERM HUP
now() { date +%s.%N; }

jq '.broker.port = 0 | .broker.endpoint = "tcp://127.0.0.1:*"' \
  "$here/../../configs/grids/local.json" >"$work/none.json"
jq '.security = "curve"' "$work/none.json" >"$work/curve.json"
if [ -n "$mesh" ]; then
  name=$(basename "$mesh")
  base64 -w0 "$mesh" >"$work/mesh.b64"
  jq -n --slurpfile s "$scene" --rawfile b "$work/mesh.b64" --arg n "$name" \
    '{scene: ($s[0] | .mesh = $n), files: [{name: $n, base64: $b}], mechanism: "posted", budget: 100}' \
    >"$work/submit.json"
else
  jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 100}' >"$work/submit.json"
fi

# One round: grid up in MODE, the job timed, grid down. Appends
# "MODE SECONDS TRANSIT STATE" to WORK/rounds.txt, the report to WORK/MODE-K.json.
round() {
  mode=$1 k=$2
  state="$work/grid-$mode-$k"
  "$bin" grid up "$work/$mode.json" --state "$state" >"$state.up.txt" 2>&1 ||
    { cat "$state.up.txt" >&2; echo "grid up ($mode) failed" >&2; exit 1; }
  url=$(jq -r .broker.url "$state/grid.json")
  token=$(head -1 "$state/token")
  t0=$(now)
  id=$(curl -sf -H "Authorization: Bearer $token" -X POST -H 'Content-Type: application/json' \
    --data-binary @"$work/submit.json" "$url/v1/jobs" | jq -r .id)
  st=none
  i=0
  while [ $i -lt 12000 ]; do # 10 minutes at most
    st=$(curl -sf -H "Authorization: Bearer $token" "$url/v1/jobs/$id" | jq -er .state) ||
      { st=unreachable; break; }
    case $st in succeeded|failed|cancelled) break ;; esac
    sleep 0.05
    i=$((i + 1))
  done
  t1=$(now)
  curl -sf -H "Authorization: Bearer $token" "$url/v1/jobs/$id/result/report.json" \
    >"$work/$mode-$k.json"
  down
  transit=$(jq '[.agents[]?.transit_seconds // 0] | add // 0' "$work/$mode-$k.json" 2>/dev/null)
  solve=$(jq '.runs[0].wall_seconds // 0' "$work/$mode-$k.json" 2>/dev/null)
  awk -v m="$mode" -v a="$t0" -v b="$t1" -v t="${transit:-0}" -v w="${solve:-0}" -v s="$st" \
    'BEGIN { printf "%s %.3f %.3f %.3f %s\n", m, b - a, t, w, s }' >>"$work/rounds.txt"
  tail -1 "$work/rounds.txt" |
    awk '{ printf "  %-5s %7.2f s (solve %.2f s, agents'\'' transit %.3f s) %s\n", $1, $2, $4, $3, $5 }'
}

echo "machine: $(getconf _NPROCESSORS_ONLN) cores, $(uname -m)"
echo "load before: $(uptime)"
for k in $(seq 1 "$rounds"); do
  if [ $((k % 2)) -eq 1 ]; then
    round none "$k"
    round curve "$k"
  else
    round curve "$k"
    round none "$k"
  fi
done
echo "load after: $(uptime)"
awk '{ n[$1]++; s[$1] += $2; t[$1] += $3; w[$1] += $4
       if (!($1 in b) || $2 < b[$1]) b[$1] = $2 }
  END {
    for (m in n)
      printf "%-5s mean %.2f s, best %.2f s over %d rounds (solve %.2f s, transit %.3f s)\n",
        m, s[m] / n[m], b[m], n[m], w[m] / n[m], t[m] / n[m]
    if (n["none"] && n["curve"])
      printf "CURVE / plaintext: %.3f (%+.2f s per job)\n", (s["curve"] / n["curve"]) / (s["none"] / n["none"]),
        s["curve"] / n["curve"] - s["none"] / n["none"]
  }' "$work/rounds.txt"
status=0
grep -qv ' succeeded$' "$work/rounds.txt" && { echo "a job did not succeed" >&2; status=1; }
first=$(ls "$work"/none-1.json)
for r in "$work"/none-*.json "$work"/curve-*.json; do
  jq -n --slurpfile a "$r" --slurpfile b "$first" \
    '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' |
    grep -q true || { echo "$(basename "$r"): the energy differs from the first round's" >&2; status=1; }
done
[ $status -eq 0 ] && echo "energies: every round's equals the first's ($(jq .runs[0].energy "$first"))"
exit $status
