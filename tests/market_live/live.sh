#!/bin/sh
# live.sh BIOTGRID LIVE_HOST WORK test [ROUNDS] [MARKET_AUDIT]
# live.sh BIOTGRID BENCH_ALLOC WORK bench [ROUNDS] [JOBS] [INFLIGHT]
# Real processes on loopback: a broker stand-in (the live market on a
# ROUTER socket, port chosen by the kernel) and `biotgrid agent --broker`
# agents.
# test: 3 rotation-fit agents and 1 sparse-solve agent on one host that
# sells 2 cores and 16 GiB: r2 and r3 may sell it (the first to register
# does, the other stands by), r1 and s1 sell no resources. After the
# market checks the simulator's audit (MARKET_AUDIT --live, jobs paying
# for what they can hold within 5 %) runs on the contracts.csv and
# agents.csv the host wrote; then the daemon selling the host is killed
# and the host must drop it and take the standby.
# bench: 8 agents (6 rotation-fit, 2 sparse-solve): allocation latency per
# mechanism, ROUNDS jobs one at a time, on a host selling 2 cores (a job
# holds both); then jobs per second at saturation, JOBS allocations
# (default 10 x ROUNDS) with INFLIGHT jobs at once (default 16), the same
# agents on a host selling 16 cores and 64 GiB (bench_alloc).
# Every process started here is killed on exit; the script then checks
# none is left.
set -u
BIOTGRID=$1 HOST=$2 WORK=$3 MODE=$4 ROUNDS=${5:-50}
rm -rf "$WORK" && mkdir -p "$WORK" || exit 1
PIDS="" ALL=""
cleanup() {
    for p in $PIDS; do kill "$p" 2>/dev/null; done
    for p in $PIDS; do wait "$p" 2>/dev/null; done
}
trap cleanup EXIT INT TERM

# start_host ARGS...: the stand-in, once it has written its endpoint.
start_host() {
    rm -f "$WORK/endpoint"
    "$HOST" "$@" &
    HOSTPID=$!
    PIDS="$PIDS $HOSTPID" ALL="$ALL $HOSTPID"
    i=0
    while [ ! -s "$WORK/endpoint" ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
    [ -s "$WORK/endpoint" ] || { echo "live.sh: host did not start"; exit 1; }
    EP=$(cat "$WORK/endpoint")
}
start_agent() { # name services cores [memory]
    OPENBLAS_NUM_THREADS=1 "$BIOTGRID" agent --name "$1" --services "$2" --slots 2 \
        --broker "$EP" --floor 1 --margin 0.2 --load-slope 0.5 --cores "$3" --memory "${4:-16}" \
        >>"$WORK/$1.log" 2>&1 &
    PIDS="$PIDS $!" ALL="$ALL $!"
    eval "PID_$1=$!"
}
bench_agents() { # cores memory
    for k in 1 2 3 4 5 6; do start_agent "r$k" rotfit "$1" "$2"; done
    start_agent s1 solve "$1" "$2"
    start_agent s2 solve "$1" "$2"
}

if [ "$MODE" = bench ]; then
    JOBS=${6:-$((10 * ROUNDS))} INFLIGHT=${7:-16}
    start_host latency "$WORK" 8 "$ROUNDS"
    bench_agents 2 16
    wait "$HOSTPID"
    RC=$?
    cleanup
    PIDS=""
    if [ "$RC" -eq 0 ]; then
        start_host saturation "$WORK" 8 "$JOBS" "$INFLIGHT"
        bench_agents 16 64
        wait "$HOSTPID"
        RC=$?
    fi
else
    AUDIT=${6:-}
    start_host "$MODE" "$WORK" 4 "$ROUNDS"
    start_agent r1 rotfit 0
    start_agent r2 rotfit 2
    start_agent r3 rotfit 2
    start_agent s1 solve 0
    i=0
    while [ ! -e "$WORK/phase2" ] && [ $i -lt 600 ]; do
        kill -0 "$HOSTPID" 2>/dev/null || break
        sleep 0.1; i=$((i + 1))
    done
    # The log of phase 1 passes the simulator's audit (both layers).
    if [ -e "$WORK/phase2" ] && [ -n "$AUDIT" ]; then
        "$AUDIT" --live --paid-ratio 0.05 "$WORK" || { echo "live.sh: the audit failed"; exit 1; }
        grep -q ',resource,' "$WORK/contracts.csv" ||
            { echo "live.sh: contracts.csv has no resource row"; exit 1; }
    fi
    # One of r2 and r3 sells the host; the broker told the other to
    # stand by, and it said so. The seller is killed.
    if [ -e "$WORK/phase2" ]; then
        seller=""
        for a in r2 r3; do grep -q "stands by" "$WORK/$a.log" || seller="$seller $a"; done
        set -- $seller
        [ $# -eq 1 ] || { echo "live.sh: not exactly one of r2, r3 sells the host ($seller)"; exit 1; }
        grep -h "stands by" "$WORK/r2.log" "$WORK/r3.log"
        # shellcheck disable=SC2154
        if [ "$1" = r2 ]; then kill -9 "$PID_r2"; else kill -9 "$PID_r3"; fi
    fi
    wait "$HOSTPID"
    RC=$?
fi
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
