#!/bin/sh
# live.sh BIOTGRID LIVE_HOST WORK test|bench [ROUNDS] [MARKET_AUDIT]
# Real processes on loopback: live_host (the broker's market on a ROUTER
# socket, port chosen by the kernel) and `biotgrid agent --broker` agents.
# test: 3 rotation-fit agents and 1 sparse-solve agent, one core each (a
# job takes three); after the market checks the simulator's audit
# (MARKET_AUDIT --live) runs on the contracts.csv and agents.csv the host
# wrote, then one rotation-fit agent is killed and the host must drop it.
# bench: 8 agents (6 rotation-fit, 2 sparse-solve), latency per mechanism.
# Every process started here is killed on exit; the script then checks
# none is left.
set -u
BIOTGRID=$1 HOST=$2 WORK=$3 MODE=$4 ROUNDS=${5:-50} AUDIT=${6:-}
rm -rf "$WORK" && mkdir -p "$WORK" || exit 1
PIDS=""
cleanup() {
    for p in $PIDS; do kill "$p" 2>/dev/null; done
    for p in $PIDS; do wait "$p" 2>/dev/null; done
}
trap cleanup EXIT INT TERM

if [ "$MODE" = bench ]; then N=8; else N=4; fi
"$HOST" "$MODE" "$WORK" "$N" "$ROUNDS" &
HOSTPID=$!
PIDS="$HOSTPID"
i=0
while [ ! -s "$WORK/endpoint" ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
[ -s "$WORK/endpoint" ] || { echo "live.sh: host did not start"; exit 1; }
EP=$(cat "$WORK/endpoint")
start_agent() { # name services
    OPENBLAS_NUM_THREADS=1 "$BIOTGRID" agent --name "$1" --services "$2" --slots 2 \
        --broker "$EP" --floor 1 --margin 0.2 --load-slope 0.5 --cores 1 --memory 8 \
        >"$WORK/$1.log" 2>&1 &
    PIDS="$PIDS $!"
    eval "PID_$1=$!"
}
if [ "$MODE" = bench ]; then
    for k in 1 2 3 4 5 6; do start_agent "r$k" rotfit; done
    start_agent s1 solve
    start_agent s2 solve
else
    start_agent r1 rotfit
    start_agent r2 rotfit
    start_agent r3 rotfit
    start_agent s1 solve
    i=0
    while [ ! -e "$WORK/phase2" ] && [ $i -lt 600 ]; do
        kill -0 "$HOSTPID" 2>/dev/null || break
        sleep 0.1; i=$((i + 1))
    done
    # The log of phase 1 passes the simulator's audit (both layers).
    if [ -e "$WORK/phase2" ] && [ -n "$AUDIT" ]; then
        "$AUDIT" --live "$WORK" || { echo "live.sh: the audit failed"; exit 1; }
        grep -q ',resource,' "$WORK/contracts.csv" ||
            { echo "live.sh: contracts.csv has no resource row"; exit 1; }
    fi
    # shellcheck disable=SC2154
    [ -e "$WORK/phase2" ] && kill -9 "$PID_r3"
fi
wait "$HOSTPID"
RC=$?
ALL=$PIDS
cleanup
PIDS=""
# No process of this run may outlive it.
for p in $ALL; do
    if kill -0 "$p" 2>/dev/null; then echo "live.sh: process $p is still running"; exit 1; fi
done
# A sanitizer build's agents report at exit; their findings fail the test.
if grep -l -E "Sanitizer|runtime error" "$WORK"/*.log 2>/dev/null; then
    echo "live.sh: an agent reported a sanitizer error"; exit 1
fi
exit $RC
