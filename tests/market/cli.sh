#!/bin/sh
# CLI tests of `biotgrid sim`. Usage: cli.sh BIOTGRID SOURCE_DIR WORK_DIR CASE [AUDIT]
#   determinism: two runs of smoke.json, same seed -> identical files;
#                another seed -> different contracts.
#   bad-config:  broken configs exit 2 with a message naming the field.
#   call-audit:  smoke.json's central market with per-type call markets for
#                the resources, on SimGrid; the audit (market_audit, AUDIT)
#                must hold and bundles must have been rented.
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
    check() { # name json field
        printf '%s' "$2" > "$WORK/$1.json"
        set +e
        "$BIN" sim "$WORK/$1.json" --out "$WORK/$1-out" --quiet 2> "$WORK/$1.err"
        rc=$?
        set -e
        [ "$rc" -eq 2 ] || { echo "FAIL: $1 exited $rc, expected 2"; cat "$WORK/$1.err"; exit 1; }
        grep -q -- "$3" "$WORK/$1.err" || { echo "FAIL: $1 message does not name $3:"; cat "$WORK/$1.err"; exit 1; }
    }
    BASE='"name":"x","seed":1,"replications":1,"duration":10,"mechanisms":["central"]'
    check unknown-key "{$BASE,\"factors\":{\"nodes\":[4],\"density\":[1]},\"colour\":1}" "colour"
    check negative-size "{$BASE,\"factors\":{\"nodes\":[-3],\"density\":[1]}}" "factors.nodes\[0\]"
    check missing-field "{\"name\":\"x\",\"seed\":1,\"replications\":1,\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]}}" "duration"
    check nested-unknown "{$BASE,\"factors\":{\"nodes\":[4],\"density\":[1]},\"central\":{\"kk\":0.5}}" "central.kk"
    check bad-k "{$BASE,\"factors\":{\"nodes\":[4],\"density\":[1]},\"central\":{\"k\":2}}" "central.k"
    check bad-market "{$BASE,\"factors\":{\"nodes\":[4],\"density\":[1]},\"central\":{\"resource_market\":\"auction\"}}" "central.resource_market"
    set +e
    "$BIN" sim "$SMOKE" --jobs 0 2>/dev/null; rc=$?
    set -e
    [ "$rc" -eq 2 ] || { echo "FAIL: --jobs 0 exited $rc"; exit 1; }
    echo "bad-config: ok"
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
*)
    echo "unknown case $CASE"; exit 2 ;;
esac
