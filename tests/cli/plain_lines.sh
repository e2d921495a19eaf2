#!/bin/sh
# plain_lines.sh BIOTGRID REST_HOST — what `biotgrid submit --wait` prints
# off a terminal, against rest_host (the broker's REST library and store on
# an ephemeral loopback port, its stand-in coordinator giving each job the
# events a live broker's job has): one readable line per event, never raw
# JSON; the progress with its fraction and unit ("running 40% (iteration
# 12)", a dynamic job's "step 5 of 20" from the event's "unit" and "of"); each contract as "contract: rotation-fit
# from agent rotfit-1, price 2.5"; the money once; "succeeded" once; and no
# "spent" line for a job that bought nothing. The host is stopped on exit.
set -u
bin=$1 host=$2
tmp=$(mktemp -d "${TMPDIR:-/tmp}/bg-plain.XXXXXX") || exit 1
pid=""
cleanup() {
    [ -n "$pid" ] && kill "$pid" 2>/dev/null && wait "$pid" 2>/dev/null
    rm -rf "$tmp"
}
trap cleanup EXIT
trap 'exit 1' INT TERM
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

"$host" "$tmp" --lifetime 120 >"$tmp/host.out" 2>"$tmp/host.err" &
pid=$!
port="" i=0
while [ -z "$port" ] && [ $i -lt 100 ] && kill -0 "$pid" 2>/dev/null; do
    sleep 0.05
    port=$(sed -n 's/^port \([0-9][0-9]*\)$/\1/p' "$tmp/host.out")
    i=$((i + 1))
done
[ -n "$port" ] || { echo "rest_host did not start: $(cat "$tmp/host.err")"; exit 1; }
BIOTGRID_TOKEN=$(sed -n 's/^token //p' "$tmp/host.out")
export BIOTGRID_TOKEN

scene() { # scene NAME: a small generated-box scene in $tmp/NAME.json
    cat >"$tmp/$1.json" <<EOF
{"name": "$1", "mesh": {"generate": "box", "cells": [4, 1, 1], "size": [4, 1, 1]},
 "material": {"mu": 1, "lambda": 1},
 "handles": [{"select": {"box": {"min": [0, 0, 0], "max": [0, 1, 1]}}},
             {"select": {"box": {"min": [4, 0, 0], "max": [4, 1, 1]}},
              "transform": {"translate": [0.5, 0, 0]}}]}
EOF
}

# wait_job NAME: submit --wait off a terminal (stdout and stderr to a file);
# sets $out, $id and $status.
wait_job() {
    scene "$1"
    "$bin" submit "$tmp/$1.json" --wait --broker "http://127.0.0.1:$port" >"$tmp/$1.out" 2>&1
    status=$?
    out=$(cat "$tmp/$1.out")
    id=$(sed -n 's/^submitted job \(j[0-9a-f]*\) .*/\1/p' "$tmp/$1.out")
    printf '%s\n' "--- submit $1 --wait (exit $status)" "$out"
}

has() { printf '%s\n' "$out" | grep -Eq -- "$1" || fail "$2: no line /$1/"; }
count() { printf '%s\n' "$out" | grep -Ec -- "$1"; }

wait_job bought
[ "$status" -eq 0 ] || fail "bought: exit $status"
has "^job $id: plan: rotation-fit, sparse-solve \\(left out: integration-step" "the plan"
has "^job $id: contract: rotation-fit from agent rotfit-1, price 2\\.5$" "the contract"
has "^job $id: bought 1 service for 2\\.5 \\(central, 0\\.050 s\\)$" "the allocation"
has "^job $id: running$" "the state change"
has "^job $id: running 40% \\(iteration 12\\)$" "the progress"
has "^job $id: solved, converged$" "the solve"
has "^  spent 2\\.5 of budget 1000 \\(central, 1 contract\\)$" "the money"
[ "$(count "succeeded")" -eq 1 ] || fail "'succeeded' printed $(count succeeded) times, not once"
has "^job $id: succeeded$" "the outcome"
[ "$(count "contract: rotation-fit")" -eq 1 ] || fail "the contract is printed more than once"
printf '%s\n' "$out" | grep -q '[{}"]' && fail "raw JSON in the plain lines"

wait_job dyn-spin
has "^job $id: running 25% \\(step 5 of 20\\)$" "a dynamic job's progress by step, as the broker names it"

wait_job free-ride
[ "$status" -eq 0 ] || fail "free-ride: exit $status"
has "^job $id: allocation: no agent is registered on the market: the job runs on the broker's configured agents, without contracts$" "what the broker said"
printf '%s\n' "$out" | grep -q "spent" && fail "a job that bought nothing has a 'spent' line"
printf '%s\n' "$out" | grep -q "contract:" && fail "a job that bought nothing shows a contract"
[ "$(count "succeeded")" -eq 1 ] || fail "free-ride: 'succeeded' printed $(count succeeded) times"

[ $failures -eq 0 ] && echo "plain_lines: ok"
exit $failures
