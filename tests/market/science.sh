#!/bin/sh
# Regressions of the market-science issues, on SimGrid, sized for the
# suite (each run takes about a second). Usage: science.sh BIOTGRID WORK CASE
#   random:        issue 30. catnets.json's settings (seed 4242) on a random
#                  platform of 48 nodes, density 1, static, 90 s of arrivals:
#                  the decentralized market and the baseline must allocate and
#                  stay within their message budgets. The tree before the fix
#                  gave catallactic 0.255 (1,609 messages per allocation, 7.9
#                  timeouts per request) and baseline 0.913 (52.9 messages).
#   baseline-size: issue 31. The baseline on the cluster, density 2, static,
#                  at 40 and 80 nodes: the cost of an allocation must not grow
#                  with the network. The tree before the fix gave 18.6 and
#                  24.1 messages per allocation and an access p99 of 5.5 and
#                  12.8 s.
# Every run also checks, for every mechanism, that messages per allocation
# stay within the bound its parameters set (bgm_budget, "message_bound").
set -eu
BIN=$1
WORK=$2
CASE=$3
mkdir -p "$WORK"
status=0 # every check runs; the case fails if one did

# config NAME TOPOLOGY NODES DENSITY MECHANISMS: catnets.json's settings
# (agents, demand, services, mechanisms' parameters) for one static
# scenario, one replication.
config() {
    cat > "$WORK/$1.json" <<EOF
{"name": "$1", "seed": 4242, "replications": 1, "duration": 90, "drain": 30,
 "mechanisms": [$5],
 "factors": {"nodes": [$3], "density": [$4], "dynamics": ["static"]},
 "network": {"topology": "$2", "latency": 0.005, "bandwidth": 125000000, "speed": 1e9,
             "speed_spread": 0.5, "message_bytes": 256},
 "agents": {"complex_per_node": 1, "service_slots": 2, "services_per_agent": 2,
            "resource_cores": 4, "resource_memory": 8, "overlay_degree": 6},
 "demand": {"interarrival_mean": 20, "work_min": 1, "work_max": 6, "valuation_mean": 3.0,
            "valuation_spread": 0.5, "deadline": 30,
            "plans": [{"services": ["rotation-fit", "sparse-solve"], "weight": 1},
                      {"services": ["rotation-fit", "sparse-solve", "integration-step"], "weight": 1}]},
 "central": {"period": 1.0, "k": 0.5, "exact_limit": 200, "optimum_limit": 250000},
 "catallactic": {"hops": 2, "discovery_timeout": 0.5, "reply_timeout": 0.5, "max_rounds": 12,
                 "learning_period": 30},
 "baseline": {"markup": 0.3, "candidates": 8}}
EOF
}

# check FILE MECHANISM SCENARIO EXPR WHY: the replication's row must satisfy
# the awk expression EXPR over its named columns (c["name"]).
check() {
    awk -F, -v mech="$2" -v scen="$3" -v why="$5" "
        NR == 1 { for (i = 1; i <= NF; i++) col[\$i] = i; next }
        { for (k in col) c[k] = \$col[k] }
        c[\"mechanism\"] == mech && c[\"scenario\"] == scen {
            seen = 1
            if (!($4)) {
                printf \"FAIL: %s %s: %s (allocation %s, messages per allocation %s, bound %s, timeouts per request %s, access p99 %s)\\n\",
                    scen, mech, why, c[\"allocation_rate\"], c[\"messages_per_allocation\"],
                    c[\"message_bound\"], c[\"timeouts_per_request\"], c[\"access_time_p99\"]
                bad = 1
            }
        }
        END { if (!seen) { printf \"FAIL: no row for %s %s\\n\", scen, mech; exit 1 } exit bad }" "$1"
}

# Every mechanism of the run within its message budget.
within_budget() {
    awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) col[$i] = i
                       if (!("message_bound" in col)) { print "FAIL: no message_bound column"; exit 1 } next }
             { m = $col["messages_per_allocation"]; b = $col["message_bound"]
               if (m == "" || b == "" || m + 0 > b + 0) {
                   printf "FAIL: %s %s: %s messages per allocation over the bound %s\n", $col["scenario"], $col["mechanism"], m, b; bad = 1 } }
             END { exit bad }' "$1"
}

case "$CASE" in
random)
    config random random 48 1 '"central", "catallactic", "baseline"'
    rm -rf "$WORK/random-out"
    "$BIN" sim "$WORK/random.json" --out "$WORK/random-out" --jobs 2 --quiet
    R=$WORK/random-out/replications.csv
    S=n48_d1_static
    # Bargaining over a wide-area network takes round trips of about 0.5 s:
    # on the cluster (0.29 s) this size allocates 0.67-0.70, so 0.5 leaves
    # room for the longer trips while the collapse (0.26) fails.
    check "$R" catallactic $S 'c["allocation_rate"] >= 0.5' "allocates too little" || status=1
    # A bought item costs a round of calls (at most 36, a proposal each) and
    # a few bargains of 2-12 offers: 200-350 on any topology; 400 is far
    # below the storm of retried rounds (1,609).
    check "$R" catallactic $S 'c["messages_per_allocation"] <= 400' "too many messages per allocation" || status=1
    # With timers that follow the measured round trips a request times out
    # about once at most (a round nobody answered, a seller gone quiet, the
    # deadline); the fixed 0.5 s timers fired 7.9 times a request.
    check "$R" catallactic $S 'c["timeouts"] <= 1.5 * c["requests"]' "too many timeouts per request" || status=1
    # The baseline buys almost everything at its first order: QUERY, LIST,
    # ORDER, ACCEPT, two AVAIL, the bundle's four and two AVAIL, CONFIRM,
    # TAKE = 14 messages, plus registration; orders that time out before
    # their answer arrives (0.5 s against 0.52 s round trips) cost more.
    check "$R" baseline $S 'c["allocation_rate"] >= 0.98' "allocates too little" || status=1
    check "$R" baseline $S 'c["messages_per_allocation"] <= 16' "too many messages per allocation" || status=1
    check "$R" central $S 'c["allocation_rate"] >= 0.98' "allocates too little" || status=1
    within_budget "$R" || status=1
    [ "$status" -eq 0 ] || exit 1
    echo "random: ok"
    ;;
baseline-size)
    config size cluster '40, 80' 2 '"baseline"'
    rm -rf "$WORK/size-out"
    "$BIN" sim "$WORK/size.json" --out "$WORK/size-out" --jobs 2 --quiet
    R=$WORK/size-out/replications.csv
    for S in n40_d2_static n80_d2_static; do
        check "$R" baseline $S 'c["allocation_rate"] >= 0.99' "allocates too little" || status=1
        # 14 messages when the first order is taken (see random), plus
        # registration: 16 leaves a refused order or two per hundred.
        check "$R" baseline $S 'c["messages_per_allocation"] <= 16' "too many messages per allocation" || status=1
        # A first-order purchase takes nine one-way trips of 0.14 s (1.12 s);
        # a refused order costs a round trip and a retry seconds more.
        check "$R" baseline $S 'c["access_time_p99"] <= 2' "access p99 too long: orders refused" || status=1
    done
    within_budget "$R" || status=1
    [ "$status" -eq 0 ] || exit 1
    echo "baseline-size: ok"
    ;;
*)
    echo "science.sh: unknown case $CASE"
    exit 2
    ;;
esac
