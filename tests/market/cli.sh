#!/bin/sh
# CLI tests of `biotgrid sim`. Usage: cli.sh BIOTGRID SOURCE_DIR WORK_DIR CASE [AUDIT]
#   determinism: two runs of smoke.json, same seed -> identical files;
#                another seed -> different contracts.
#   bad-config:  broken configs, files and platforms exit 2 with a message
#                naming the file and the field (or line and column);
#                --help lists the options.
#   user-platform: a user SimGrid platform next to the config; its host
#                speeds set the run times.
#   audit-detects: the audit fails on a doctored log (a double purchase,
#                a memory part shorter than its service).
#   audit-live:  --live counts a job's cores at a seller as its widest
#                service's: a 2-core host selling one job a core for each
#                of two rotation-fit agents and two for its sparse solve
#                passes; the same rows split over two jobs fail. With
#                --paid-ratio 0.05 the one job paying for each phase's cores
#                (4 core-units for 2 it can hold) fails; paying for its
#                widest phase once (the live columns use and clearing: the
#                sparse solve's row holds 2 and pays 0) passes.
#   wire:        smoke.json and a shortened shock.json (one replication, the
#                shock kept) under --engine inprocess and --engine wire: every
#                output file equal byte for byte (cmp), and the audit (AUDIT)
#                holds for both.
#   call-audit:  smoke.json's central market with per-type call markets for
#                the resources, on SimGrid; the audit (market_audit, AUDIT)
#                must hold and bundles must have been rented.
#   topology-factor: factors.topology (random, scale-free) with static and
#                churn: --jobs 2 and --jobs 1 on SimGrid, and --engine
#                inprocess and wire, give the same files byte for byte;
#                summary.json, replications.csv and contracts.csv name each
#                scenario's topology; each topology's rows equal those of
#                the same config on that topology alone (the levels share
#                their random streams) and the two topologies' rows differ
#                on SimGrid; a config without the factor names no topology.
set -eu
BIN=$1
SRC=$2
WORK=$3
CASE=$4
SMOKE=$SRC/configs/experiments/smoke.json
mkdir -p "$WORK"

case "$CASE" in
determinism)
    rm -rf "$WORK/a" "$WORK/b" "$WORK/c"
    "$BIN" sim "$SMOKE" --out "$WORK/a" --jobs 2 --quiet
    "$BIN" sim "$SMOKE" --out "$WORK/b" --jobs 1 --quiet
    for f in summary.json replications.csv contracts.csv agents.csv \
             allocation_rate_vs_size.svg price_rotation-fit.svg; do
        cmp "$WORK/a/$f" "$WORK/b/$f" || { echo "FAIL: $f differs between identical runs"; exit 1; }
    done
    grep -q '"seed":' "$WORK/a/summary.json" || { echo "FAIL: seed missing from summary"; exit 1; }
    sed 's/"seed": *[0-9]*/"seed": 777/' "$SMOKE" > "$WORK/other-seed.json"
    "$BIN" sim "$WORK/other-seed.json" --out "$WORK/c" --jobs 2 --quiet
    if cmp -s "$WORK/a/contracts.csv" "$WORK/c/contracts.csv"; then
        echo "FAIL: a different seed gave identical contracts"; exit 1
    fi
    echo "determinism: ok"
    ;;
bad-config)
    # check NAME CONTENT PATTERN...: the config exits 2 and its message
    # matches every extended regular expression given.
    check() {
        name=$1 content=$2
        shift 2
        printf '%s' "$content" > "$WORK/$name.json"
        expect_bad "$name" "$WORK/$name.json" "$@"
    }
    expect_bad() {
        name=$1 file=$2
        shift 2
        set +e
        "$BIN" sim "$file" --out "$WORK/$name-out" --quiet 2> "$WORK/$name.err"
        rc=$?
        set -e
        [ "$rc" -eq 2 ] || { echo "FAIL: $name exited $rc, expected 2"; cat "$WORK/$name.err"; exit 1; }
        for pattern in "$@"; do
            grep -Eq -- "$pattern" "$WORK/$name.err" || { echo "FAIL: $name: message does not match /$pattern/:"; cat "$WORK/$name.err"; exit 1; }
        done
    }
    BASE='"name":"x","seed":1,"replications":1,"duration":10,"mechanisms":["central"]'
    FAC='"factors":{"nodes":[4],"density":[1]}'
    check unknown-key "{$BASE,$FAC,\"colour\":1}" "unknown-key\.json: unknown key 'colour' \(expected: name, seed, replications, duration, drain, mechanisms, factors"
    check negative-size "{$BASE,\"factors\":{\"nodes\":[-3],\"density\":[1]}}" "factors\.nodes\[0\]: -3 is out of range \[1, 20000\]"
    check missing-field "{\"name\":\"x\",\"seed\":1,\"replications\":1,\"mechanisms\":[\"central\"],$FAC}" "missing-field\.json: duration: missing"
    check nested-unknown "{$BASE,$FAC,\"central\":{\"kk\":0.5}}" "central: unknown key 'kk' \(expected: period, k, exact_limit"
    check bad-k "{$BASE,$FAC,\"central\":{\"k\":2}}" "central\.k: 2 is out of range"
    check bad-market "{$BASE,$FAC,\"central\":{\"resource_market\":\"auction\"}}" "central\.resource_market: must be exchange or call"
    check syntax "{$BASE,
  $FAC,,
}" "syntax\.json: malformed JSON at line 2, column [0-9]+"
    check duplicate "{$BASE,$FAC,\"seed\":2}" "duplicate\.json: key 'seed' appears twice"
    check topology-repeat "{$BASE,\"factors\":{\"nodes\":[4],\"density\":[1],\"topology\":[\"random\",\"random\"]}}" "topology-repeat\.json: factors\.topology\[1\]: repeats 'random'"
    check topology-twice "{$BASE,\"factors\":{\"nodes\":[4],\"density\":[1],\"topology\":[\"random\"]},\"network\":{\"topology\":\"cluster\"}}" "topology-twice\.json: factors\.topology: network\.topology is given too"
    check empty "" "empty\.json: empty file"
    # A missing file: exit 2, the path once, and the reason.
    expect_bad missing "$WORK/no-such-dir/none.json" "none\.json: cannot open: No such file or directory"
    [ "$(grep -o 'none\.json' "$WORK/missing.err" | wc -l)" -eq 1 ] || { echo "FAIL: the missing path is not printed exactly once:"; cat "$WORK/missing.err"; exit 1; }
    # A platform that is not there (relative: next to the config), and one
    # SimGrid cannot load: exit 2 naming the file, no SimGrid backtrace.
    mkdir -p "$WORK/platdir"
    printf '%s' "{$BASE,$FAC,\"network\":{\"platform\":\"nowhere.xml\"}}" > "$WORK/platdir/noplat.json"
    expect_bad noplat "$WORK/platdir/noplat.json" "network\.platform: cannot open '.*platdir/nowhere\.xml': No such file or directory"
    printf 'not a platform\n' > "$WORK/platdir/garbage.xml"
    printf '%s' "{$BASE,$FAC,\"network\":{\"platform\":\"garbage.xml\"}}" > "$WORK/platdir/badplat.json"
    expect_bad badplat "$WORK/platdir/badplat.json" "garbage\.xml: SimGrid cannot load this platform"
    [ "$(wc -l < "$WORK/badplat.err")" -le 2 ] || { echo "FAIL: bad platform message is not short:"; cat "$WORK/badplat.err"; exit 1; }
    set +e
    "$BIN" sim "$SMOKE" --jobs 0 2> "$WORK/jobs.err"; rc=$?
    set -e
    [ "$rc" -eq 2 ] && grep -q -- "--jobs '0' must be an integer in \[1, 256\]" "$WORK/jobs.err" || { echo "FAIL: --jobs 0 exited $rc"; cat "$WORK/jobs.err"; exit 1; }
    "$BIN" sim --help > "$WORK/help.txt"
    for word in --out --jobs --engine --timing --quiet summary.json "Exit status"; do
        grep -q -- "$word" "$WORK/help.txt" || { echo "FAIL: sim --help does not mention $word"; exit 1; }
    done
    echo "bad-config: ok"
    ;;
user-platform)
    # A user platform named relative to the config's folder, run from
    # another working directory; its host speed (2e8 flops, five times
    # below network.speed) sets the run times the economics price: a
    # rotation-fit unit (2e9 flops, one core) takes 10 s.
    rm -rf "$WORK/up"
    mkdir -p "$WORK/up/cfg"
    cat > "$WORK/up/cfg/two-hosts.xml" <<'XML'
<?xml version='1.0'?>
<!DOCTYPE platform SYSTEM "https://simgrid.org/simgrid.dtd">
<platform version="4.1">
  <zone id="site" routing="Full">
    <host id="a" speed="200Mf"/>
    <host id="b" speed="200Mf"/>
    <host id="c" speed="200Mf"/>
    <link id="ab" bandwidth="125MBps" latency="5ms"/>
    <link id="ac" bandwidth="125MBps" latency="5ms"/>
    <link id="bc" bandwidth="125MBps" latency="5ms"/>
    <route src="a" dst="b"><link_ctn id="ab"/></route>
    <route src="a" dst="c"><link_ctn id="ac"/></route>
    <route src="b" dst="c"><link_ctn id="bc"/></route>
  </zone>
</platform>
XML
    sed -e 's/"mechanisms": *\[[^]]*\]/"mechanisms": ["central"]/' \
        -e 's/"replications": *[0-9]*/"replications": 1/' \
        -e 's/"nodes": *\[[^]]*\]/"nodes": [6]/' \
        -e 's/"network": *{/"network": {"platform": "two-hosts.xml", /' "$SMOKE" > "$WORK/up/cfg/exp.json"
    grep -q '"platform": "two-hosts.xml"' "$WORK/up/cfg/exp.json" || { echo "FAIL: could not derive the config"; exit 1; }
    (cd "$WORK" && "$BIN" sim up/cfg/exp.json --out up/out --quiet)
    awk -F, '$4 == "service" && $11 == "rotation-fit" { n++; d = ($8 - $7) / $12; if (d < 9.99 || d > 10.01) bad++ }
             END { if (n == 0 || bad > 0) { printf "FAIL: %d of %d rotation-fit services not at 10 s per unit\n", bad, n; exit 1 } }' \
        "$WORK/up/out/contracts.csv"
    echo "user-platform: ok"
    ;;
audit-detects)
    # The audit finds what it claims to: a request bought twice, and a
    # memory part that ends before its service.
    AUDIT=$5
    rm -rf "$WORK/aud"
    "$BIN" sim "$SMOKE" --out "$WORK/aud/ok" --engine inprocess --quiet
    "$AUDIT" "$WORK/aud/ok"
    mkdir -p "$WORK/aud/twice" "$WORK/aud/short"
    for d in twice short; do cp "$WORK/aud/ok/"*.csv "$WORK/aud/ok/summary.json" "$WORK/aud/$d/"; done
    awk -F, 'NR > 1 && $4 == "service" && !done { print; done = 1 } { print }' "$WORK/aud/ok/contracts.csv" > "$WORK/aud/twice/contracts.csv"
    awk -F, 'BEGIN { OFS = "," } NR > 1 && $11 == "memory" && !done { $8 = $8 - 1; done = 1 } { print }' "$WORK/aud/ok/contracts.csv" > "$WORK/aud/short/contracts.csv"
    set +e
    "$AUDIT" "$WORK/aud/twice" > "$WORK/aud/twice.out" 2>&1; rc1=$?
    "$AUDIT" "$WORK/aud/short" > "$WORK/aud/short.out" 2>&1; rc2=$?
    set -e
    [ "$rc1" -eq 1 ] && grep -q "bought twice" "$WORK/aud/twice.out" || { echo "FAIL: a double purchase passed the audit"; cat "$WORK/aud/twice.out"; exit 1; }
    [ "$rc2" -eq 1 ] && grep -q "does not cover" "$WORK/aud/short.out" || { echo "FAIL: a short memory part passed the audit"; cat "$WORK/aud/short.out"; exit 1; }
    echo "audit-detects: ok"
    ;;
audit-live)
    AUDIT=$5
    rm -rf "$WORK/live"
    mkdir -p "$WORK/live/one" "$WORK/live/two"
    for d in one two; do
        cat > "$WORK/live/$d/agents.csv" <<'CSV'
scenario,replication,mechanism,agent,role,good,capacity,limit
g,0,posted,1,basic,rotation-fit,4,1
g,0,posted,2,basic,rotation-fit,4,1
g,0,posted,3,basic,sparse-solve,2,1
g,0,posted,9,resource,cores,2,1e-05
g,0,posted,9,resource,memory,16,2e-06
CSV
    done
    # rows JOB_OF_REQUEST_2: one job's three services, each with its cores
    # and memory for the service's whole interval.
    rows() {
        echo "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,good,quantity,price,buyer_limit,seller_limit"
        echo "g,0,posted,service,1,0,0,10,j1,1,rotation-fit,1,1.2,2,1"
        echo "g,0,posted,service,2,0,0,10,$1,2,rotation-fit,1,1.2,2,1"
        echo "g,0,posted,service,3,0,0,10,j1,3,sparse-solve,1,1.2,2,1"
        for r in 1 2 3; do
            q=1; [ "$r" -eq 3 ] && q=2
            echo "g,0,posted,resource,$r,0,0,10,$r,9,cores,$q,1e-05,2e-05,1e-05"
            echo "g,0,posted,resource,$r,0,0,10,$r,9,memory,$q,2e-06,4e-06,2e-06"
        done
    }
    rows j1 > "$WORK/live/one/contracts.csv"
    rows j2 > "$WORK/live/two/contracts.csv"
    "$AUDIT" --live "$WORK/live/one" || { echo "FAIL: one job's phases sharing two cores failed the live audit"; exit 1; }
    set +e
    "$AUDIT" --live --paid-ratio 0.05 "$WORK/live/one" > "$WORK/live/one.out" 2>&1; rc=$?
    set -e
    [ "$rc" -eq 1 ] && grep -q "pay for 2.0000 cores units per unit they can hold" "$WORK/live/one.out" ||
        { echo "FAIL: a job paying for every phase's cores passed --paid-ratio"; cat "$WORK/live/one.out"; exit 1; }
    mkdir -p "$WORK/live/once"
    sed 's/,posted,/,central,/' "$WORK/live/one/agents.csv" > "$WORK/live/once/agents.csv"
    {
        echo "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,good,quantity,price,buyer_limit,seller_limit,use,clearing"
        for r in 1 2 3; do
            echo "g,0,central,service,$r,0,0,10,j1,$r,$( [ "$r" -eq 3 ] && echo sparse-solve || echo rotation-fit),1,1.2,2,1,1,$r"
            paid=1 use=1; [ "$r" -eq 3 ] && paid=0 use=2
            echo "g,0,central,resource,$r,0,0,10,$r,9,cores,$paid,1e-05,2e-05,1e-05,$use,"
            echo "g,0,central,resource,$r,0,0,10,$r,9,memory,$use,2e-06,4e-06,2e-06,$use,"
        done
    } > "$WORK/live/once/contracts.csv"
    "$AUDIT" --live --paid-ratio 0.05 "$WORK/live/once" > "$WORK/live/once.out" 2>&1 &&
        grep -q "paid/holdable 1.0000 (cores 20/20" "$WORK/live/once.out" ||
        { echo "FAIL: a job paying for its widest phase once failed --paid-ratio"; cat "$WORK/live/once.out"; exit 1; }
    set +e
    "$AUDIT" --live "$WORK/live/two" > "$WORK/live/two.out" 2>&1; rc=$?
    set -e
    [ "$rc" -eq 1 ] && grep -q "over capacity (3 > 2 cores" "$WORK/live/two.out" || { echo "FAIL: two jobs holding three of two cores passed the live audit"; cat "$WORK/live/two.out"; exit 1; }
    # A seller lost before it delivered anything: its service row settled
    # at 0 units at t=4, its cores and memory ended then. It paid for four
    # seconds of resources and earned nothing: marked lost, that is the
    # loss it bears; unmarked, the same rows are an agent paying more for
    # resources than it earned. Request 4 is the service bought again.
    for d in lost unmarked; do
        mkdir -p "$WORK/live/$d"
        cp "$WORK/live/one/agents.csv" "$WORK/live/$d/"
        l=1; [ "$d" = unmarked ] && l=0
        {
            echo "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,good,quantity,price,buyer_limit,seller_limit,use,clearing,lost"
            echo "g,0,posted,service,1,0,0,4,j1,1,rotation-fit,0,1.2,2,1,1,,$l"
            echo "g,0,posted,resource,1,0,0,4,1,9,cores,1,1e-05,2e-05,1e-05,1,,$l"
            echo "g,0,posted,resource,1,0,0,4,1,9,memory,1,2e-06,4e-06,2e-06,1,,$l"
            echo "g,0,posted,service,4,4,4,10,j1,2,rotation-fit,1,1.2,2,1,1,,0"
            echo "g,0,posted,resource,4,4,4,10,2,9,cores,1,1e-05,2e-05,1e-05,1,,0"
            echo "g,0,posted,resource,4,4,4,10,2,9,memory,1,2e-06,4e-06,2e-06,1,,0"
        } > "$WORK/live/$d/contracts.csv"
    done
    "$AUDIT" --live "$WORK/live/lost" > "$WORK/live/lost.out" 2>&1 ||
        { echo "FAIL: a lost seller's settled rows failed the live audit"; cat "$WORK/live/lost.out"; exit 1; }
    set +e
    "$AUDIT" --live "$WORK/live/unmarked" > "$WORK/live/unmarked.out" 2>&1; rc=$?
    set -e
    [ "$rc" -eq 1 ] && grep -q "basic agent 1 spent .* on resources, earned 0" "$WORK/live/unmarked.out" ||
        { echo "FAIL: a seller paying resources for nothing passed the live audit unmarked"; cat "$WORK/live/unmarked.out"; exit 1; }
    echo "audit-live: ok"
    ;;
call-audit)
    AUDIT=$5
    rm -rf "$WORK/call"
    sed -e 's/"mechanisms": *\[[^]]*\]/"mechanisms": ["central"]/' \
        -e 's/"central": *{/"central": {"resource_market": "call", /' "$SMOKE" > "$WORK/call.json"
    grep -q '"resource_market": "call"' "$WORK/call.json" || { echo "FAIL: could not derive the config"; exit 1; }
    "$BIN" sim "$WORK/call.json" --out "$WORK/call" --jobs 2 --quiet
    "$AUDIT" "$WORK/call"
    grep -q ',resource,.*,memory,' "$WORK/call/contracts.csv" || { echo "FAIL: no memory rented"; exit 1; }
    grep -q '"resource_market":[[:space:]]*"call"' "$WORK/call/summary.json" || { echo "FAIL: summary does not say call"; exit 1; }
    if grep -q '"winner_determination":[[:space:]]*"[eg]' "$WORK/call/summary.json"; then
        echo "FAIL: the combinatorial exchange ran in call mode"; exit 1
    fi
    echo "call-audit: ok"
    ;;
topology-factor)
    T=$WORK/topo
    rm -rf "$T"
    mkdir -p "$T"
    # exp NAME TOPOLOGY-JSON: a small experiment, the topology given either
    # as factors.topology or as network.topology.
    exp() {
        case "$2" in
        '['*) fac=", \"topology\": $2"; net="" ;;
        *) fac=""; net="\"topology\": \"$2\", " ;;
        esac
        cat > "$T/$1.json" <<EOF
{"name": "$1", "seed": 31, "replications": 2, "duration": 60, "drain": 30,
 "mechanisms": ["central", "catallactic", "baseline"],
 "factors": {"nodes": [12], "density": [1], "dynamics": ["static", "churn"]$fac},
 "dynamics": {"static": {}, "churn": {"node_failure_rate": 0.004, "node_repair_mean": 20,
              "link_failure_rate": 0.004, "link_repair_mean": 5}},
 "network": {$net"latency": 0.005, "degree": 4},
 "demand": {"interarrival_mean": 15, "deadline": 30}}
EOF
    }
    exp both '["random", "scale-free"]'
    exp random random
    exp scale-free scale-free
    # same A B WHAT: every file of A equals B's, and they hold as many.
    same() {
        n=0
        for f in "$1"/*; do
            cmp "$f" "$2/$(basename "$f")" || { echo "FAIL: $(basename "$f") differs: $3"; exit 1; }
            n=$((n + 1))
        done
        [ "$n" -eq "$(ls "$2" | wc -l)" ] && [ "$n" -ge 5 ] || { echo "FAIL: $3: $n files against $(ls "$2" | wc -l)"; exit 1; }
    }
    "$BIN" sim "$T/both.json" --out "$T/j2" --jobs 2 --quiet
    "$BIN" sim "$T/both.json" --out "$T/j1" --jobs 1 --quiet
    same "$T/j2" "$T/j1" "--jobs 2 against --jobs 1"
    "$BIN" sim "$T/both.json" --out "$T/inprocess" --engine inprocess --jobs 2 --quiet
    "$BIN" sim "$T/both.json" --out "$T/wire" --engine wire --jobs 1 --quiet
    same "$T/inprocess" "$T/wire" "--engine inprocess against wire"
    # summary.json: 2 topologies x 2 dynamics x 3 mechanisms results, each
    # naming its topology, which prefixes its scenario.
    jq -e '[.results[] | select(.topology as $t | .scenario | startswith($t + "_n12_d1_"))] | length == 12' \
        "$T/j2/summary.json" > /dev/null || { echo "FAIL: summary.json does not name each scenario's topology"; exit 1; }
    jq -e '[.results[] | .topology] | (map(select(. == "random")) | length) == 6 and (map(select(. == "scale-free")) | length) == 6' \
        "$T/j2/summary.json" > /dev/null || { echo "FAIL: summary.json does not hold 6 results per topology"; exit 1; }
    head -n 1 "$T/j2/replications.csv" | grep -q '^scenario,topology,nodes,density,dynamics,' ||
        { echo "FAIL: replications.csv has no topology column"; exit 1; }
    awk -F, 'NR > 1 && index($1, $2 "_") != 1 { bad = 1 } NR > 1 { n++ } END { exit bad || n != 24 }' "$T/j2/replications.csv" ||
        { echo "FAIL: replications.csv rows do not name their topology"; exit 1; }
    # Each level equals its topology run alone: the same rows once the
    # topology's name is taken out.
    for t in random scale-free; do
        "$BIN" sim "$T/$t.json" --out "$T/$t" --jobs 2 --quiet
        head -n 1 "$T/$t/replications.csv" | grep -q '^scenario,nodes,' ||
            { echo "FAIL: a config without the factor names a topology in replications.csv"; exit 1; }
        if grep -q '"topology"' "$T/$t/summary.json"; then
            echo "FAIL: a config without the factor names a topology in summary.json"; exit 1
        fi
        awk -F, -v t="$t" 'NR > 1 && $2 == t { sub("^" t "_", "", $1); line = $1; for (i = 3; i <= NF; i++) line = line "," $i; print line }' \
            "$T/j2/replications.csv" > "$T/$t.factor.csv"
        tail -n +2 "$T/$t/replications.csv" > "$T/$t.alone.csv"
        [ -s "$T/$t.alone.csv" ] && cmp "$T/$t.factor.csv" "$T/$t.alone.csv" ||
            { echo "FAIL: the $t level of the factor differs from $t alone"; exit 1; }
        grep "^$t""_" "$T/j2/contracts.csv" | sed "s/^$t""_//" > "$T/$t.factor.contracts"
        tail -n +2 "$T/$t/contracts.csv" > "$T/$t.alone.contracts"
        [ -s "$T/$t.alone.contracts" ] && cmp "$T/$t.factor.contracts" "$T/$t.alone.contracts" ||
            { echo "FAIL: the $t level's contracts differ from $t alone"; exit 1; }
    done
    # The topology is not ignored: on SimGrid the two levels' rows differ.
    if cmp -s "$T/random.alone.csv" "$T/scale-free.alone.csv"; then
        echo "FAIL: random and scale-free gave the same replications"; exit 1
    fi
    echo "topology-factor: ok"
    ;;
wire)
    AUDIT=$5
    sed -e 's/"replications": *[0-9]*/"replications": 1/' \
        -e 's/"duration": *[0-9]*/"duration": 360/' \
        "$SRC/configs/experiments/shock.json" > "$WORK/shock-short.json"
    grep -q '"shock"' "$WORK/shock-short.json" || { echo "FAIL: the shortened shock lost its shock"; exit 1; }
    for exp in "$SMOKE" "$WORK/shock-short.json"; do
        name=$(basename "$exp" .json)
        rm -rf "$WORK/$name-inprocess" "$WORK/$name-wire"
        "$BIN" sim "$exp" --out "$WORK/$name-inprocess" --engine inprocess --jobs 2 --quiet
        "$BIN" sim "$exp" --out "$WORK/$name-wire" --engine wire --jobs 2 --quiet
        n=0
        for f in "$WORK/$name-inprocess"/*; do
            b=$(basename "$f")
            cmp "$f" "$WORK/$name-wire/$b" || { echo "FAIL: $name: $b differs between engines"; exit 1; }
            n=$((n + 1))
        done
        m=$(ls "$WORK/$name-wire" | wc -l)
        [ "$n" -eq "$m" ] || { echo "FAIL: $name: $n files inprocess, $m wire"; exit 1; }
        [ "$n" -ge 5 ] || { echo "FAIL: $name: only $n output files"; exit 1; }
        "$AUDIT" "$WORK/$name-inprocess"
        "$AUDIT" "$WORK/$name-wire"
        echo "wire: $name: $n files identical, audit ok"
    done
    ;;
*)
    echo "unknown case $CASE"; exit 2 ;;
esac
