#!/bin/sh
# broker_jobs.sh BIOTGRID AGENT_SCRIPTS WORKDIR MESH STATIC_SCENE DYNAMIC_SCENE
# A real broker process and real agents on ephemeral loopback ports: each
# scene submitted through REST runs on the agents and its report's energy
# equals `biotgrid solve` in process (1e-10 relative), and so does a
# scene whose mesh file MESH is uploaded with it; the static job
# never calls the integration-step agent; the dynamic one stores its .pvd
# and frames; an unknown job is a 404, cancelling an ended one a 409.
# Every process started here is stopped (trap), and none is left.
set -u
bin=$1 scripts=$2 work=$3 mesh=$4
shift 4
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
rm -rf "$work"
mkdir -p "$work"
fail=0
cleanup() {
  stop_broker "$work" broker || fail=1
  sh "$scripts/stop_agents.sh" "$work/agents" >/dev/null || fail=1
  if [ -s "$work/broker.ready" ]; then
    pid=$(cut -d' ' -f3 "$work/broker.ready")
    if kill -0 "$pid" 2>/dev/null; then echo "FAIL: broker pid $pid left" >&2; fail=1; fi
  fi
}
trap 'cleanup; exit 1' INT TERM

sh "$scripts/start_agents.sh" "$bin" "$work/agents" r1:rotfit r2:rotfit sv:solve ig:integ \
  >"$work/agents.txt" || exit 1
ep() { cut -d' ' -f1 "$work/agents/$1.ready"; }
cat >"$work/broker.json" <<JSON
{"name": "test", "port": 0, "endpoint": "tcp://127.0.0.1:*", "state_dir": "$work/state",
 "agents": [{"endpoint": "$(ep r1)", "services": "rotfit"},
            {"endpoint": "$(ep r2)", "services": "rotfit"},
            {"endpoint": "$(ep sv)", "services": "solve"},
            {"endpoint": "$(ep ig)", "services": "integ"}]}
JSON
start_broker "$bin" "$work" broker "$work/broker.json" || { cleanup; exit 1; }
url=$(cut -d' ' -f1 "$work/broker.ready")

n=0
for scene in "$@"; do
  n=$((n + 1))
  jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 100}' \
    >"$work/submit$n.json"
  code=$(bcurl -s -o "$work/job$n.json" -w '%{http_code}' -X POST \
    -H 'Content-Type: application/json' --data-binary @"$work/submit$n.json" "$url/v1/jobs")
  [ "$code" = 202 ]; check $? "$scene: submit answers 202 (got $code)"
  id=$(jq -r .id "$work/job$n.json")
  state=$(wait_job "$url" "$id" 300)
  [ "$state" = succeeded ]; check $? "$scene: job $id succeeded (got $state)"
  bcurl -sf "$url/v1/jobs/$id" >"$work/detail$n.json"
  jq -e '.trace | length > 1' "$work/detail$n.json" >/dev/null
  check $? "$scene: the job resource holds the run's trace ($(jq '.trace | length' "$work/detail$n.json") points)"
  bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report$n.json"
  jq -e --slurpfile r "$work/report$n.json" '(.trace | length) == ($r[0].runs[0].trace | length)' \
    "$work/detail$n.json" >/dev/null
  check $? "$scene: the job's trace has the report's points"
  jq -e '.market.mechanism == "posted" and .market.budget == 100 and .market.spent == 0 and
         (.market.contracts | length) == 0 and .market.allocation_latency_seconds >= 0 and
         (.market.error_vs_time_and_money | length) == (.runs[0].trace | length)' \
    "$work/report$n.json" >/dev/null
  check $? "$scene: the report's market section (mechanism, budget, nothing spent, no contracts)"
  "$bin" solve "$scene" --quiet --out "$work/local$n" >/dev/null 2>&1
  jq -n --slurpfile a "$work/report$n.json" --slurpfile b "$work/local$n/report.json" \
    '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' \
    | grep -q true
  check $? "$scene: energy $(jq .runs[0].energy "$work/report$n.json") equals solve's $(jq .runs[0].energy "$work/local$n/report.json") (1e-10 relative)"
  calls=$(jq --arg e "$(ep ig)" '[.agents[] | select(.endpoint == $e) | .calls] | add // 0' \
    "$work/report$n.json")
  if jq -e '.runs[0].method == "newton" or .runs[0].method == "local-global"' \
     "$work/report$n.json" >/dev/null; then
    [ "$calls" = 0 ]; check $? "$scene: the static job called the integration-step agent $calls times"
    jq -e '[.plan.services[].name] | (length > 0 and index("integration-step") == null)' \
      "$work/report$n.json" >/dev/null
    check $? "$scene: the static job's plan has no integration-step"
  fi
  bcurl -sf "$url/v1/jobs/$id/result" >"$work/files$n.json"
  if jq -e '.runs[0].method == "variational" or .runs[0].method == "backward-euler"' \
     "$work/report$n.json" >/dev/null; then
    jq -e '[.files[].name | select(endswith(".pvd"))] | length == 1' "$work/files$n.json" >/dev/null
    check $? "$scene: the dynamic job stored its .pvd"
    frames=$(jq '[.files[].name | select(test("-[0-9]{6}[.]vtu$"))] | length' "$work/files$n.json")
    [ "$frames" -gt 1 ]; check $? "$scene: the dynamic job stored $frames frames"
    bcurl -sf "$url/v1/jobs/$id/result/$(jq -r '[.files[].name | select(endswith(".pvd"))][0]' \
      "$work/files$n.json")" | grep -q 'file="[a-z-]*-[0-9]*[.]vtu"'
    check $? "$scene: the .pvd names frames stored beside it"
  fi
  for f in report.json error-vs-time.svg result.vtu; do
    jq -e --arg f "$f" '[.files[].name] | index($f) != null' "$work/files$n.json" >/dev/null
    check $? "$scene: result has $f"
  done
  bcurl -sf "$url/v1/jobs/$id/events" --max-time 10 >"$work/events$n.txt"
  grep -q '"no agent is registered on the market' "$work/events$n.txt"
  check $? "$scene: the allocation event says no agent is registered on the market"
  grep -q '^event: trace' "$work/events$n.txt" || grep -q '"points"' "$work/events$n.txt"
  check $? "$scene: the trace is an event"
  code=$(bcurl -s -o /dev/null -w '%{http_code}' -X POST "$url/v1/jobs/$id/cancel")
  [ "$code" = 409 ]; check $? "$scene: cancelling an ended job is 409 (got $code)"
done
# A scene with its mesh uploaded: the coordinator unpacks it for the solve.
mkdir -p "$work/upload"
cp "$mesh" "$work/upload/"
mname=$(basename "$mesh")
cat >"$work/upload/scene.json" <<JSON
{"mesh": "$mname", "material": {"mu": 1, "lambda": 1},
 "handles": [{"name": "base", "select": {"vertices": [0, 1, 2]}},
             {"name": "tip", "select": {"vertices": [4]}, "transform": {"translate": [0.1, 0, 0]}}],
 "solver": {"method": "newton", "tolerance": 1e-10}}
JSON
base64 -w0 "$mesh" >"$work/upload/mesh.b64"
jq -n --slurpfile s "$work/upload/scene.json" --rawfile b "$work/upload/mesh.b64" --arg n "$mname" \
  '{scene: $s[0], files: [{name: $n, base64: $b}], mechanism: "central", budget: 5}' \
  >"$work/upload/submit.json"
id=$(bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$work/upload/submit.json" \
  "$url/v1/jobs" | jq -r .id)
state=$(wait_job "$url" "$id" 120)
[ "$state" = succeeded ]; check $? "uploaded mesh: job $id succeeded (got $state)"
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/upload/report.json"
"$bin" solve "$work/upload/scene.json" --quiet --out "$work/upload/local" >/dev/null 2>&1
jq -n --slurpfile a "$work/upload/report.json" --slurpfile b "$work/upload/local/report.json" \
  '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-10 * ($b[0].runs[0].energy | fabs)' \
  | grep -q true
check $? "uploaded mesh: energy equals solve's (1e-10 relative)"

n=$(bcurl -sf "$url/v1/agents" | jq '[.agents[] | select(.source == "config")] | length')
[ "$n" = 4 ]; check $? "GET /v1/agents lists the broker's 4 agents (got $n)"
code=$(bcurl -s -o /dev/null -w '%{http_code}' "$url/v1/jobs/j0000000000000000")
[ "$code" = 404 ]; check $? "an unknown job is 404 (got $code)"

cleanup
exit $fail
