#!/bin/sh
# client.sh BIOTGRID REST_HOST JSON_GET SOURCE_DIR — the REST client
# commands end to end against a real HTTP server: rest_host (bgb_rest +
# bgb_store, with its stand-in coordinator) on an ephemeral loopback port in
# a temporary folder. Exit statuses, the broker's messages and the --json
# documents (parsed back with cJSON by json_get) are checked; every server
# this script starts is stopped on exit, whatever happens.
set -u
bin=$1 host=$2 json=$3 src=$4
tmp=$(mktemp -d "${TMPDIR:-/tmp}/bgb-client.XXXXXX") || exit 1
pids=""
cleanup() {
    for p in $pids; do
        kill "$p" 2>/dev/null
        wait "$p" 2>/dev/null
    done
    rm -rf "$tmp"
}
trap cleanup EXIT
trap 'exit 1' INT TERM
failures=0

fail() {
    echo "FAIL: $*" >&2
    failures=$((failures + 1))
}

# start_host NAME [rest_host options]: sets $port (the host's stdout names it).
start_host() {
    name=$1
    shift
    mkdir -p "$tmp/$name"
    "$host" "$tmp/$name" --lifetime 120 "$@" >"$tmp/$name.out" 2>"$tmp/$name.err" &
    pid=$!
    pids="$pids $pid"
    eval "pid_$name=\$pid"
    port=""
    i=0
    while [ $i -lt 100 ]; do
        port=$(sed -n 's/^port \([0-9][0-9]*\)$/\1/p' "$tmp/$name.out")
        if [ -n "$port" ]; then
            BIOTGRID_TOKEN=$(sed -n 's/^token //p' "$tmp/$name.out")
            export BIOTGRID_TOKEN
            return 0
        fi
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.05
        i=$((i + 1))
    done
    echo "rest_host $name did not start:" >&2
    cat "$tmp/$name.err" >&2
    exit 1
}

# check CODE PATTERN COMMAND...: exit status CODE and output matching PATTERN
# (extended regular expression); the output is kept in $out.
check() {
    code=$1 pattern=$2
    shift 2
    out=$("$@" 2>&1)
    status=$?
    if [ "$status" -ne "$code" ]; then
        fail "$* exited $status, expected $code; output: $out"
    elif ! printf '%s\n' "$out" | grep -Eq -- "$pattern"; then
        fail "$*: output does not match /$pattern/: $out"
    fi
}

# get PATH: the value at PATH of the JSON document in $out.
get() {
    printf '%s' "$out" | "$json" "$1"
}

scene() { # scene FILE NAME [MATERIAL]: a small generated-box scene
    material=${3-}
    [ -n "$material" ] || material='{"mu": 1, "lambda": 1}'
    cat >"$1" <<EOF
{"name": "$2", "mesh": {"generate": "box", "cells": [4, 1, 1], "size": [4, 1, 1]},
 "material": $material,
 "handles": [{"select": {"box": {"min": [0, 0, 0], "max": [0, 1, 1]}}},
             {"select": {"box": {"min": [4, 0, 0], "max": [4, 1, 1]}},
              "transform": {"translate": [0.5, 0, 0]}}]}
EOF
}

start_host main
main_port=$port
b="--broker http://127.0.0.1:$main_port"
fixtures=$src/tests/fixtures

# Submit: the mesh is found through --mesh-path and uploaded; a resubmit
# with the same Idempotency-Key returns the same job.
check 0 '"id"' "$bin" submit "$fixtures/scenes/mesh-path.json" --mesh-path "$fixtures/mesh" \
    --idempotency-key key-1 --mechanism posted --budget 12.5 --json $b
id1=$(get id)
[ "$(get mechanism)" = posted ] || fail "submit --json: mechanism $(get mechanism), expected posted"
[ "$(get budget)" = 12.5 ] || fail "submit --json: budget $(get budget), expected 12.5"
printf '%s\n' "$id1" | grep -Eq '^j[0-9a-f]{16}$' || fail "submit --json: id '$id1'"
check 0 '"id"' "$bin" submit "$fixtures/scenes/mesh-path.json" --mesh-path "$fixtures/mesh" \
    --idempotency-key key-1 --mechanism posted --budget 12.5 --json $b
[ "$(get id)" = "$id1" ] || fail "idempotent resubmit gave $(get id), expected $id1"
# The same key with another body is refused, naming the key: a replay
# would hide that the client sent something else.
check 2 "422 Idempotency-Key reused: Idempotency-Key 'key-1' was used for job $id1 with another body" \
    "$bin" submit "$fixtures/scenes/mesh-path.json" --mesh-path "$fixtures/mesh" \
    --idempotency-key key-1 --budget 13 $b
check 0 "^submitted job j[0-9a-f]{16} \\(queued, mechanism central, budget 1000\\)" \
    "$bin" submit "$fixtures/scenes/mesh-path.json" --mesh-path "$fixtures/mesh" $b
id2=$(printf '%s\n' "$out" | sed -n 's/^submitted job \(j[0-9a-f]*\) .*/\1/p')
[ "$id2" != "$id1" ] || fail "a submit without a key reused job $id1"

# A file that is nowhere is the client's error, naming the scene and the field.
check 2 "mesh-path\\.json: mesh: data-kept-elsewhere/two-tets\\.mesh not found" \
    env BIOTGRID_MESH_PATH= "$bin" submit "$fixtures/scenes/mesh-path.json" $b

# --wait follows the events to the end: plain lines when not on a terminal.
scene "$tmp/ok.json" ok-1
check 0 "job j[0-9a-f]{16}: running 40% \\(iteration 12\\)" "$bin" submit "$tmp/ok.json" --wait $b
printf '%s\n' "$out" | grep -Eq "^job j[0-9a-f]{16}: succeeded$" ||
    fail "submit --wait: no 'succeeded' line: $out"
printf '%s\n' "$out" | grep -Eq "^job j[0-9a-f]{16}: running$" ||
    fail "submit --wait: no 'running' line: $out"
check 0 '"state"' "$bin" submit "$tmp/ok.json" --wait --json $b
[ "$(get state)" = succeeded ] || fail "submit --wait --json: state $(get state)"
# --out waits and downloads the result: the files `result` lists, and with
# --json stdout is the job document alone.
check 0 "^$tmp/res/w/report\\.json \\([0-9]+ bytes\\)" "$bin" submit "$tmp/ok.json" --out "$tmp/res/w" $b
[ -s "$tmp/res/w/report.json" ] || fail "submit --out: no report.json in $tmp/res/w"
check 0 '"state"' "$bin" submit "$tmp/ok.json" --out "$tmp/res/wj" --json $b
[ "$(get state)" = succeeded ] || fail "submit --out --json: state $(get state)"
[ -s "$tmp/res/wj/report.json" ] || fail "submit --out --json: no report.json"

# On a terminal (a pseudo-terminal from script(1), util-linux) --wait draws a
# progress bar fed by the events instead of the lines.
if command -v script >/dev/null 2>&1; then
    check 0 "j[0-9a-f]{16} \\[#{12}\\.{18}\\]  40% running, iteration 12" \
        script -qec "'$bin' submit '$tmp/ok.json' --wait $b" /dev/null
    printf '%s\n' "$out" | grep -Eq "\\[#{30}\\] 100% succeeded" ||
        fail "submit --wait on a terminal: no full bar: $out"
    printf '%s\n' "$out" | grep -q "running 40%" &&
        fail "submit --wait on a terminal printed plain lines: $out"
else
    fail "script(1) is needed for the terminal test"
fi

# A job that fails: --wait exits 1 with the reason.
scene "$tmp/fail.json" fail-1
check 1 "failed: the test host fails jobs named fail" "$bin" submit "$tmp/fail.json" --wait $b

# status, then the result files, byte for byte what was uploaded.
i=0
while :; do
    check 0 '"state"' "$bin" status "$id1" --json $b
    [ "$(get state)" = succeeded ] && break
    i=$((i + 1))
    [ $i -lt 100 ] || { fail "job $id1 never succeeded: $out"; break; }
    sleep 0.1
done
[ "$(get links.result)" = "/v1/jobs/$id1/result" ] || fail "status --json: links.result"
check 0 "^job $id1: succeeded" "$bin" status "$id1" $b
check 0 "input-two-tets\\.mesh \\([0-9]+ bytes\\)" "$bin" result "$id1" --out "$tmp/res/a" $b
cmp -s "$tmp/res/a/input-two-tets.mesh" "$fixtures/mesh/two-tets.mesh" ||
    fail "result: input-two-tets.mesh differs from the uploaded mesh"
out=$(cat "$tmp/res/a/report.json")
[ "$(get scene)" = mesh-path ] || fail "report.json: scene $(get scene)"
[ "$(get inputs.0.name)" = two-tets.mesh ] || fail "the mesh was uploaded as $(get inputs.0.name)"
check 0 '"files"' "$bin" result "$id1" --out "$tmp/res/b" --json $b
[ "$(get files.#)" = 2 ] || fail "result --json: $(get files.#) files, expected 2"

# Cancel a job that has not ended; again: 409 with the broker's message.
scene "$tmp/hold.json" hold-1
check 0 "submitted" "$bin" submit "$tmp/hold.json" $b
hold=$(printf '%s\n' "$out" | sed -n 's/^submitted job \(j[0-9a-f]*\) .*/\1/p')
check 2 "409 No result: job $hold is queued: it has no result yet" \
    "$bin" result "$hold" --out "$tmp/res/c" $b
check 0 "^cancelled $hold" "$bin" cancel "$hold" $b
check 2 "409 Job already ended" "$bin" cancel "$hold" $b
check 0 '"reason"' "$bin" status "$hold" --json $b
[ "$(get state)" = cancelled ] || fail "cancelled job is $(get state)"
[ "$(get reason)" = "cancelled by the client" ] || fail "cancel reason: $(get reason)"

# A bad scene: 422 naming the field; unknown job: 404.
scene "$tmp/bad.json" bad-1 '{"mu": -1, "lambda": 1}'
check 2 "422 Invalid scene: scene: material: unstable material mu = -1.*\\(field scene\\.material\\)" "$bin" submit "$tmp/bad.json" $b
check 2 "404 No such job" "$bin" status j0000000000000000 $b
check 2 "404" "$bin" cancel nonsense $b
check 2 "400 Invalid parameter: state: 'bogus'" "$bin" jobs --state bogus $b
# The agent directory and the market, as documents the client passes through.
check 0 '"agents"' "$bin" agents --json $b
[ "$(get agents.#)" = 0 ] || fail "agents: $(get agents.#) agents on a host with none"
check 0 '"mechanisms"' "$bin" market --json $b
[ "$(get name)" = rest-host ] || fail "market: name $(get name), expected rest-host"

# jobs: every page followed (pages of 2), the same list as one page; --limit; --state.
check 0 '"jobs"' "$bin" jobs --json --page 500 $b
all=$(get jobs)
total=$(get jobs.#)
[ "$total" = 9 ] || fail "jobs: $total jobs, expected 9"
check 0 '"jobs"' "$bin" jobs --json --page 2 $b
[ "$(get jobs)" = "$all" ] || fail "jobs in pages of 2 differ from one page"
[ "$(get jobs.0.id)" = "$id1" ] || fail "jobs: first is $(get jobs.0.id), expected $id1"
check 0 '"jobs"' "$bin" jobs --json --limit 3 --page 2 $b
[ "$(get jobs.#)" = 3 ] || fail "jobs --limit 3: $(get jobs.#) jobs"
check 0 '"jobs"' "$bin" jobs --json --state cancelled $b
[ "$(get jobs.#)" = 1 ] && [ "$(get jobs.0.id)" = "$hold" ] || fail "jobs --state cancelled: $out"
check 0 "^9 jobs$" "$bin" jobs $b

# The broker from the environment, then from the local grid's state file.
check 0 "^9 jobs$" env BIOTGRID_BROKER="http://127.0.0.1:$main_port" "$bin" jobs
mkdir -p "$tmp/grid"
printf '{"name": "local", "broker": {"url": "http://127.0.0.1:%s"}, "agents": []}\n' \
    "$main_port" >"$tmp/grid/grid.json"
check 0 "^9 jobs$" env -u BIOTGRID_BROKER BIOTGRID_GRID_DIR="$tmp/grid" "$bin" jobs

# An oversized body: 413 from a host with a small cap.
start_host small --max-body 300
small_port=$port
check 2 "413 Request body too large" "$bin" submit "$fixtures/scenes/mesh-path.json" \
    --mesh-path "$fixtures/mesh" --broker "http://127.0.0.1:$small_port"
kill "$pid"
wait "$pid" || fail "rest_host small exited $? on SIGTERM"
# ... and once it is gone, connection refused names the URL and how to start a broker.
check 1 "cannot reach the broker at http://127.0.0.1:$small_port .*biotgrid grid up" \
    "$bin" jobs --broker "http://127.0.0.1:$small_port"

# A broker that stops while --wait follows a job: the stream is resumed a
# few times, then the client says the broker cannot be reached (exit 1).
start_host stopping
stop_port=$port
"$bin" submit "$tmp/hold.json" --wait --broker "http://127.0.0.1:$stop_port" \
    >"$tmp/wait.out" 2>&1 &
waiter=$!
pids="$pids $waiter"
i=0
until grep -q "^submitted job" "$tmp/wait.out" || [ $i -ge 100 ]; do
    sleep 0.05
    i=$((i + 1))
done
kill "$pid_stopping"
wait "$pid_stopping" || fail "rest_host stopping exited $? on SIGTERM"
wait "$waiter"
status=$?
[ "$status" -eq 1 ] || fail "submit --wait on a stopped broker exited $status, expected 1"
grep -q "cannot reach the broker at http://127.0.0.1:$stop_port" "$tmp/wait.out" ||
    fail "submit --wait on a stopped broker: $(cat "$tmp/wait.out")"

# Usage errors.
check 2 "--mechanism: unknown mechanism 'bogus'" "$bin" submit "$tmp/ok.json" --mechanism bogus $b
check 2 "--budget: '-3' is not a positive number" "$bin" submit "$tmp/ok.json" --budget -3 $b
check 2 "missing --out DIR" "$bin" result "$id1" $b
check 2 "missing ID" "$bin" status $b

# The host stops cleanly on SIGTERM (under the sanitizers: without a leak report).
kill "$pid_main"
wait "$pid_main" || fail "rest_host main exited $? on SIGTERM: $(cat "$tmp/main.err")"

echo "client.sh: $failures failure(s)"
[ "$failures" -eq 0 ]
