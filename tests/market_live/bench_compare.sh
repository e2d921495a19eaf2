#!/bin/sh
# bench_compare.sh BEFORE_BUILD AFTER_BUILD WORK [ROUNDS] [JOBS] [TIMES]
# The allocation benchmark (live.sh bench: latency per mechanism one job at
# a time, then jobs per second at saturation) for two builds of the tree,
# alternated TIMES times (default 2) in one run so that both see the same
# machine; each build directory holds bin/biotgrid (broker/biotgrid in
# builds of older trees) and
# tests/market_live/bench_alloc (a tree without bench_alloc gets it by
# copying bench_alloc.c and live_net.[ch] into its tests/market_live and
# building them as this tree's CMakeLists.txt does: they use only market
# calls older trees have). Each run is headed by the machine's load
# (uptime). Not part of the test suite; market_live.bench_smoke runs a
# short bench.
set -u
BEFORE=$1 AFTER=$2 WORK=$3 ROUNDS=${4:-30} JOBS=${5:-200} TIMES=${6:-2}
HERE=$(cd "$(dirname "$0")" && pwd)
cmd() { if [ -x "$1/bin/biotgrid" ]; then echo "$1/bin/biotgrid"; else echo "$1/broker/biotgrid"; fi; }
for b in "$BEFORE" "$AFTER"; do
    [ -x "$(cmd "$b")" ] || { echo "bench_compare: $b/bin/biotgrid is missing"; exit 2; }
    [ -x "$b/tests/market_live/bench_alloc" ] ||
        { echo "bench_compare: $b/tests/market_live/bench_alloc is missing"; exit 2; }
done
mkdir -p "$WORK" || exit 1
rc=0
i=1
while [ "$i" -le "$TIMES" ]; do
    for which in before after; do
        if [ "$which" = before ]; then b=$BEFORE; else b=$AFTER; fi
        echo "== $which ($b), run $i; $(uptime)"
        sh "$HERE/live.sh" "$(cmd "$b")" "$b/tests/market_live/bench_alloc" \
            "$WORK/$which-$i" bench "$ROUNDS" "$JOBS" 16 2>"$WORK/$which-$i.err" || rc=1
    done
    i=$((i + 1))
done
exit $rc
