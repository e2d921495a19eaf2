#!/bin/sh
# bench_grid.sh BIOTGRID SCENE MESH [WORKDIR]
# A scene submitted to a local grid (grid up: 4 agents and the broker, on
# ephemeral loopback ports; the agents sell on the broker's live market)
# against `biotgrid solve` in process, in the same run: prints the load,
# both wall times (submit → succeeded, solve start → end), their ratio,
# what the job bought, and checks the energies agree (1e-10 relative). The
# mesh is uploaded with the scene. Run by hand; prints figures, asserts no
# speed.
set -u
bin=$1 scene=$2 mesh=$3 work=${4:-/tmp/bench-grid}
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$work"
mkdir -p "$work"
state="$work/grid"
trap '"$bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM
now() { date +%s.%N; }
name=$(basename "$mesh")
echo "load before: $(uptime)"
t0=$(now)
"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1 || { echo "solve failed" >&2; exit 1; }
t1=$(now)
"$bin" grid up "$here/../../configs/grids/local.json" --state "$state" --broker-port 0 \
  --broker-endpoint 'tcp://127.0.0.1:*' >/dev/null || exit 1
url=$(jq -r .broker.url "$state/grid.json")
token=$(head -1 "$state/token")
base64 -w0 "$mesh" >"$work/mesh.b64"
jq -n --slurpfile s "$scene" --rawfile b "$work/mesh.b64" --arg n "$name" \
  '{scene: ($s[0] | .mesh = $n), files: [{name: $n, base64: $b}], mechanism: "posted", budget: 100}' \
  >"$work/submit.json"
t2=$(now)
id=$(curl -sf -H "Authorization: Bearer $token" -X POST -H 'Content-Type: application/json' --data-binary @"$work/submit.json" \
  "$url/v1/jobs" | jq -r .id)
st=none
i=0
while [ $i -lt 12000 ]; do  # 10 minutes at most; a refused request ends it
  st=$(curl -sf -H "Authorization: Bearer $token" "$url/v1/jobs/$id" | jq -er .state) ||
    { st="unreachable"; break; }
  case $st in succeeded|failed|cancelled) break ;; esac
  sleep 0.05
  i=$((i + 1))
done
t3=$(now)
curl -sf -H "Authorization: Bearer $token" "$url/v1/jobs/$id/result/report.json" \
  >"$work/report.json"
"$bin" grid down --state "$state" >/dev/null
echo "load after: $(uptime)"
echo "state: $st"
awk -v a="$t0" -v b="$t1" -v c="$t2" -v d="$t3" 'BEGIN {
  printf "biotgrid solve (in process): %.2f s\ngrid job (submit -> succeeded): %.2f s\nratio grid / solve: %.2f\n",
    b - a, d - c, (d - c) / (b - a) }'
jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" \
  '"energy grid \($a[0].runs[0].energy) solve \($b[0].runs[0].energy)"' -r
jq -r '.market | "market: \(.market // "none"), mechanism \(.mechanism), \(.contracts | length) contracts, spent \(.spent) of \(.budget), allocation \(.allocation_latency_seconds) s"' \
  "$work/report.json"
jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" \
  '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' |
  grep -q true || { echo "the energies differ" >&2; exit 1; }
[ "$st" = succeeded ]
