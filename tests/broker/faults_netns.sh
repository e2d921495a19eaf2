#!/bin/sh
# faults_netns.sh BIOTGRID AGENT_SCRIPTS WORKDIR SCENE MESH_DIR MARKET_AUDIT
# faults_netns.sh --cleanup WORKDIR
# A network fault: an agent cut off from the broker and its coordinator by
# a link set down, then up again. Needs root (CAP_NET_ADMIN): a network
# namespace and a veth pair are made here, named from WORKDIR (unique per
# build folder); without them the test reports SKIP (exit 77), never a
# pass. Everything made here is removed at the end, on failure too, and
# by `--cleanup WORKDIR` (the CTest cleanup fixture) after a test that was
# killed.
#
# The broker binds the veth's host side; rotation-fit and integration-step
# agents run on loopback, the only sparse-solve agent inside the namespace
# (its own host, with its own resource seller), so the job (SCENE with
# local/global) buys its sparse solve there. The loopback host sells 8
# cores: a replacement is a purchase of its own, whose cores do not share
# the job's phases there (README, Limits). Once the job runs a second
# sparse-solve agent starts on loopback; the link is first slowed for
# DELAY_FOR seconds (tc netem, DELAY_MS each way with jitter, or where the
# kernel has no netem a tc tbf token bucket of SHAPE_RATE: slower answers,
# no loss may be declared), then goes down for LINK_DOWN seconds,
# then up. Then:
#   - nothing is declared lost while the link is only slow;
#   - the job notices the lost agent and buys the sparse solve again from
#     the loopback agent ("agent_lost", "rebought", "resumed" events);
#   - the cut-off agent's late answers reach the coordinator once the link
#     is up, and are discarded ("late_answer" events);
#   - the job succeeds with `biotgrid solve`'s energy (1e-9 relative);
#   - the contract log has no duplicate contract: the live audit passes
#     (one service row per request, capacities, money), and the cut-off
#     agent's contract ended at the loss, settled pro rata;
#   - every process is stopped and the namespace and veth are gone.
set -u
LINK_DOWN=8 DELAY_MS=150 DELAY_FOR=3 SHAPE_RATE=2mbit
names() { # WORKDIR → ns, host and agent veth names, subnet prefix
  h=$(printf '%s' "$1" | cksum | cut -d' ' -f1)
  tag=$(printf '%08x' "$h" | cut -c1-8)
  ns="bgf$tag-ns" vh="bgf${tag}h" va="bgf${tag}a"
  # 172.31.X.Y/30, X and Y from the same hash (Y a multiple of 4).
  x=$((h % 250 + 1)) y=$(((h / 250) % 63 * 4))
  ip_host="172.31.$x.$((y + 1))" ip_agent="172.31.$x.$((y + 2))"
}
teardown() { # WORKDIR: processes, then namespace and veth (idempotent)
  _w=$1
  [ -s "$_w/broker.ready" ] && [ ! -s "$_w/broker.rc" ] &&
    kill -TERM "$(cut -d' ' -f3 "$_w/broker.ready")" 2>/dev/null
  if [ -s "$_w/cut.ready" ] && [ ! -s "$_w/cut.rc" ]; then
    kill -TERM "$(cut -d' ' -f2 "$_w/cut.ready")" 2>/dev/null
  fi
  for _d in agents agents2; do
    [ -d "$_w/$_d" ] && sh "$scripts/stop_agents.sh" "$_w/$_d" >/dev/null 2>&1
  done
  _i=0
  while [ $_i -lt 100 ]; do
    _alive=0
    for _f in broker cut; do
      [ -s "$_w/$_f.ready" ] && [ ! -s "$_w/$_f.rc" ] && _alive=1
    done
    [ $_alive -eq 0 ] && break
    sleep 0.1
    _i=$((_i + 1))
  done
  for _f in broker cut; do
    if [ -s "$_w/$_f.ready" ] && [ ! -s "$_w/$_f.rc" ]; then
      _pid=$(awk '{ print $NF }' "$_w/$_f.ready")
      kill -KILL "$_pid" 2>/dev/null
    fi
  done
  names "$_w"
  ip link del "$vh" 2>/dev/null
  ip netns pids "$ns" 2>/dev/null | while read -r _p; do kill -KILL "$_p" 2>/dev/null; done
  ip netns del "$ns" 2>/dev/null
  ! ip netns list 2>/dev/null | grep -q "^$ns\b" && ! ip link show "$vh" >/dev/null 2>&1
}

if [ "${1:-}" = --cleanup ]; then
  scripts=$(cd "$(dirname "$0")/../agents" && pwd)
  teardown "$2"
  exit $?
fi
bin=$1 scripts=$2 work=$3 scene=$4 mesh_dir=$5 audit=$6
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
fail=0
rm -rf "$work"
mkdir -p "$work"
names "$work"
# Whatever happens (a failed step, an error, a signal), the processes, the
# namespace and the veth go.
trap 'teardown "$work"' EXIT
trap 'exit 1' INT TERM HUP
# Namespaces need root (CAP_NET_ADMIN): without them the test cannot run.
if ! ip netns add "$ns" 2>"$work/netns.txt"; then
  echo "SKIP: cannot make a network namespace: $(cat "$work/netns.txt")"
  exit 77
fi
if ! ip link add "$vh" type veth peer name "$va" 2>>"$work/netns.txt" ||
   ! ip link set "$va" netns "$ns" || ! ip addr add "$ip_host/30" dev "$vh" ||
   ! ip link set "$vh" up || ! ip netns exec "$ns" ip addr add "$ip_agent/30" dev "$va" ||
   ! ip netns exec "$ns" ip link set "$va" up || ! ip netns exec "$ns" ip link set lo up; then
  echo "SKIP: cannot make a veth pair into the namespace: $(cat "$work/netns.txt")"
  teardown "$work"
  exit 77
fi
echo "namespace $ns: $va $ip_agent <-> $vh $ip_host"

# The agents' endpoint is beyond loopback: without CURVE keys the broker
# and the agent refuse it unless told --insecure (this test is about the
# link, not the keys; multihost/ tests the keys across namespaces).
jq -n --arg ep "tcp://$ip_host:*" --arg dir "$work/broker" \
  '{name: "netfault", port: 0, endpoint: $ep, state_dir: $dir, insecure: true}' >"$work/broker.json"
start_broker "$bin" "$work" broker "$work/broker.json"
check $? "the broker starts, its agents' endpoint on $ip_host"
[ $fail -eq 0 ] || exit 1 # nothing below can pass (the EXIT trap tears down)
url=$(cut -d' ' -f1 "$work/broker.ready")
bep=$(cut -d' ' -f2 "$work/broker.ready")
BG_AGENT_OPTIONS="--broker $bep --insecure --cores 8" sh "$scripts/start_agents.sh" "$bin" "$work/agents" \
  rotfit-1:rotfit rotfit-2:rotfit integ-1:integ >/dev/null
check $? "the loopback agents start"
( ip netns exec "$ns" "$bin" agent --listen "tcp://$ip_agent:*" --services solve --slots 4 \
    --name cut-1 --floor 0.5 --broker "$bep" --insecure --ready-file "$work/cut.ready" \
    >"$work/cut.log" 2>&1 </dev/null
  echo $? >"$work/cut.rc" ) >/dev/null 2>&1 </dev/null &
n=$(agents_matching "$url" '.alive and (.services | length) > 0' 4 200)
[ "${n:-0}" -eq 4 ]; check $? "4 agents sell on the market, one of them in the namespace, over the veth (got $n)"
[ $fail -eq 0 ] || exit 1
cut_pid=$(cut -d' ' -f2 "$work/cut.ready" 2>/dev/null)

# BG_FAULT_LG_ITERS local/global iterations (3,000 by default; fewer on
# the small scene the sanitizer build uses), all of them: a tolerance no
# run reaches, so the job lasts as long on every scene and machine load.
jq --argjson n "${BG_FAULT_LG_ITERS:-3000}" '.solver.method = "local-global" | .solver.max_iterations = $n
  | .solver.tolerance = 1e-300' "$scene" >"$work/scene.json"
"$bin" solve "$work/scene.json" --mesh-path "$mesh_dir" --quiet --out "$work/local" \
  >"$work/local.txt" 2>&1
[ $? -le 1 ] && [ -s "$work/local/report.json" ]; check $? "biotgrid solve (the reference)"
id=$("$bin" submit "$work/scene.json" --mesh-path "$mesh_dir" --mechanism posted --budget 1000 \
  --broker "$url" --json 2>"$work/submit.txt" | jq -r .id)
[ -n "$id" ] && [ "$id" != null ]; check $? "the job is accepted ($id)"
i=0 st=none
while [ $i -lt 1200 ]; do
  doc=$(bcurl -sf "$url/v1/jobs/$id")
  st=$(echo "$doc" | jq -r 'if .state == "running" and (.progress.fraction // 0) > 0.02
                            then "progressing" else .state end')
  case $st in progressing|succeeded|failed|cancelled) break ;; esac
  sleep 0.1
  i=$((i + 1))
done
[ "$st" = progressing ]; check $? "the job runs (got $st)"
[ $fail -eq 0 ] || exit 1
seller=$(echo "$doc" | jq -r '[.contracts[] | select(.service == "sparse-solve")][0].agent')
[ "$seller" = cut-1 ]; check $? "its sparse solve was bought from the agent in the namespace ($seller)"
# Now a loopback sparse-solve agent: the one to buy it from again.
BG_AGENT_OPTIONS="--broker $bep --insecure --cores 8" sh "$scripts/start_agents.sh" "$bin" "$work/agents2" \
  solve-1:solve >/dev/null
check $? "a loopback sparse-solve agent starts"
n=$(agents_matching "$url" '.name == "solve-1" and .alive' 1 200)
[ "${n:-0}" -eq 1 ]; check $? "it sells on the market"

# A slow link first: DELAY_MS each way, jitter a fifth of it (tc netem);
# on a kernel without netem, a token bucket of SHAPE_RATE that queues the
# payloads (tc tbf). Either way the qdisc must have held packets back.
shape() { # DEV [ip netns exec NS]: the slow link's qdisc on DEV
  _dev=$1
  shift
  "$@" tc qdisc add dev "$_dev" root netem delay "${DELAY_MS}ms" "$((DELAY_MS / 5))ms" \
    2>/dev/null && return 0
  "$@" tc qdisc add dev "$_dev" root tbf rate "$SHAPE_RATE" burst 4kb latency 2s
}
t_delay=$(date +%s.%N)
shape "$vh" && shape "$va" ip netns exec "$ns"
check $? "the link slowed down ($(tc qdisc show dev "$vh" | cut -d' ' -f2-))"
sleep $DELAY_FOR
held=$( (tc -s qdisc show dev "$vh"; ip netns exec "$ns" tc -s qdisc show dev "$va") |
  awk '/Sent/ { for (i = 1; i < NF; i++) if ($i == "overlimits") o += $(i + 1); n++ }
       /^qdisc netem/ { netem++ } END { print (netem ? 1 : o + 0) }')
[ "${held:-0}" -ge 1 ]; check $? "the qdisc held packets back (overlimits $held)"
tc qdisc del dev "$vh" root && ip netns exec "$ns" tc qdisc del dev "$va" root
check $? "the delay removed after $DELAY_FOR s"
[ "$(bcurl -sf "$url/v1/jobs/$id" | jq -r .state)" = running ]
check $? "the job still runs on the slow link"
ip link set "$vh" down
t_cut=$(date +%s.%N)
echo "link $vh down"
sleep $LINK_DOWN
ip link set "$vh" up
echo "link $vh up after $LINK_DOWN s"
st=$(wait_job "$url" "$id" 1200)
[ "$st" = succeeded ]; check $? "the job succeeds (got $st)"
[ "$st" = succeeded ] || bcurl -sf "$url/v1/jobs/$id" >&2
bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events.txt"
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"
ev() { awk -v k="$1" '/^event: / { e = $2 } /^data: / && e == k { sub(/^data: /, ""); print }' "$work/events.txt"; }
lost=$(ev agent_lost | head -1)
[ "$(ev agent_lost | wc -l)" -eq 1 ]; check $? "one loss declared, not two"
awk -v c="$t_cut" -v l="$(echo "$lost" | jq -r '.time // 0')" 'BEGIN { exit !(l >= c) }'
check $? "no loss declared while the link was only slow (since $t_delay)"
[ -n "$lost" ] && echo "$lost" | jq -e '.agent == "cut-1" and .service == "sparse-solve"' >/dev/null
check $? "the coordinator found cut-1 lost ($lost)"
again=$(ev rebought | head -1)
[ -n "$again" ] && echo "$again" | jq -e '.lost == "cut-1" and .agent == "solve-1" and .cost > 0' >/dev/null
check $? "and bought its sparse solve again elsewhere ($again)"
resumed=$(ev resumed | head -1)
[ -n "$resumed" ]; check $? "the solve resumed ($resumed)"
awk -v c="$t_cut" -v r="$(echo "$resumed" | jq -r .time)" \
  'BEGIN { printf "from the cut: computing again after %.2f s\n", r - c }'
late=$(ev late_answer | jq -s '[.[] | select(.agent == "cut-1" and .outcome == "discarded") | .count] | add // 0')
[ "$late" -ge 1 ]; check $? "cut-1's late answers were discarded once the link was up ($late)"
jq -n --slurpfile a "$work/report.json" --slurpfile b "$work/local/report.json" \
  '($a[0].runs[0].energy - $b[0].runs[0].energy) | fabs <= 1e-9 * ($b[0].runs[0].energy | fabs)' \
  | grep -q true
check $? "the energy equals biotgrid solve's to 1e-9"
jq -e '.faults[0].lost == "cut-1" and .faults[0].late_answers >= 1' "$work/report.json" >/dev/null
check $? "report.json lists the fault and its late answers"
contracts_closed "$url" "$work/contracts.csv"
bcurl -sf "$url/v1/market/agents.csv" >"$work/agents.csv"
"$audit" --live "$work" >"$work/audit.txt" 2>&1
check $? "no duplicate contract: the live audit passes ($(cat "$work/audit.txt"))"
awk -F, -v j="$id" 'NR > 1 && $4 == "service" && $9 == j && $11 == "sparse-solve" { n++; if ($12 < 1) settled++ }
  END { exit !(n == 2 && settled == 1) }' "$work/contracts.csv"
check $? "contracts.csv: two sparse-solve contracts for the job, the cut-off one settled pro rata"
t_up=$(now)
n=$(agents_matching "$url" '.name == "cut-1" and .alive' 1 300)
[ "${n:-0}" -ge 1 ]; check $? "cut-1 registered again once its link was up ($(awk -v a="$t_up" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }') s after the audit)"

stop_broker "$work" broker; check $? "the broker stops"
teardown "$work"; check $? "the namespace, the veth and every process are gone"
trap - EXIT
sh "$scripts/no_agents_left.sh" "$work/agents" >/dev/null &&
  sh "$scripts/no_agents_left.sh" "$work/agents2" >/dev/null
check $? "no loopback agent is left"
[ -z "$cut_pid" ] || [ ! -d "/proc/$cut_pid" ] || [ "$(sed 's/.*) //' "/proc/$cut_pid/stat" | cut -c1)" = Z ]
check $? "the namespace's agent is gone"
exit $fail
