#!/bin/sh
# limits.sh BIOTGRID SLOW_CLIENTS WORKDIR
# The broker's limits hold by default, against a real broker on ephemeral
# loopback ports (no agents: nothing here needs a job to run):
#   - it prints the limits in force, sized to the machine;
#   - the 75-byte request asking for 180 million tetrahedra is refused at
#     once (with or without its material) and the broker stays small;
#   - a body that is not JSON is 415, and problem details name no server path;
#   - a user's jobs in flight (429) and stored bytes (413) are capped, and
#     deleting an ended job frees its bytes;
#   - 300 clients holding half-sent or silent connections do not keep
#     /healthz from answering;
#   - the store is readable by its owner alone.
set -u
bin=$1 slow=$2 work=$3
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
broker_test_begin "$work"
broker_config "$work" limits '{"max_jobs_in_flight": 2, "max_stored_bytes": 3000}'
start_broker "$bin" "$work" b "$work/broker.json" || exit 1
url=$(cut -d' ' -f1 "$work/b.ready")
pid=$(cut -d' ' -f3 "$work/b.ready")
port=${url##*:}

grep -Eq '^  max_elements [0-9]+, max_vertices [0-9]+ per job \(estimated peak [0-9.]+ GiB' "$work/b.log"
check $? "the broker prints the job size caps it derived from the machine"
grep -q '^  max_jobs_in_flight 2, max_stored_bytes 3000 per user$' "$work/b.log"
check $? "and the limits its configuration set"

post() { # post BODY [HEADER...]: the status into $work/status, the body into $work/out
  _body=$1
  shift
  bcurl -s -o "$work/out" -w '%{http_code}' -X POST -H 'Content-Type: application/json' "$@" \
    --data-binary "$_body" "$url/v1/jobs" >"$work/status"
}
elapsed() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.2f", b - a }'; }

t0=$(now)
post '{"scene": {"mesh": {"generate": "box", "cells": [1000, 1000, 30], "size": [1, 1, 1]}}}'
took=$(elapsed "$t0")
[ "$(cat "$work/status")" = 422 ] && grep -q '"field":"scene.material"' "$work/out"
check $? "the 75-byte request without a material is refused for it (422, $took s)"
post '{"scene": {"mesh": {"generate": "box", "cells": [1000, 1000, 30], "size": [1, 1, 1]}, "material": {"mu": 1, "lambda": 1}}}'
[ "$(cat "$work/status")" = 422 ] && grep -q '"field":"scene.mesh.cells"' "$work/out" &&
  grep -q 'job-too-large' "$work/out"
check $? "with its material, refused for its size naming mesh.cells"
awk -v s="$took" 'BEGIN { exit !(s < 1.0) }'
check $? "refused within a second ($took s)"
peak=$(awk '/^VmHWM:/ { print $2 }' "/proc/$pid/status")
[ "${peak:-999999}" -lt 204800 ]
check $? "the broker's peak memory stays below 200 MB (${peak:-?} kB)"

bcurl -s -o "$work/out" -w '%{http_code}' -X POST -H 'Content-Type: text/plain' \
  --data-binary '{"scene": {}}' "$url/v1/jobs" >"$work/status"
[ "$(cat "$work/status")" = 415 ] && grep -q '"field":"Content-Type"' "$work/out"
check $? "a text/plain body is refused with 415 naming Content-Type"

post '{"scene": {"mesh": "../../etc/passwd", "material": {"mu": 1, "lambda": 1}}}'
[ "$(cat "$work/status")" = 422 ] && ! grep -q "$work" "$work/out"
check $? "a path that leaves the job's folder is refused without naming a server path"
post '{"scene": {"mesh": "missing.mesh", "material": {"mu": 1, "lambda": 1}}, "files": [{"name": "other.off", "base64": "T0ZG"}]}'
[ "$(cat "$work/status")" = 422 ] && grep -q 'missing.mesh not found' "$work/out" &&
  ! grep -q "$work" "$work/out"
check $? "a file the job did not upload is named as the client wrote it, not by its server path"

small='{"scene": {"mesh": {"generate": "box", "cells": [2, 1, 1], "size": [2, 1, 1]}, "material": {"mu": 1, "lambda": 1}, "handles": [{"select": {"box": {"min": [0, 0, 0], "max": [0, 1, 1]}}}]}}'
post "$small"
[ "$(cat "$work/status")" = 202 ]; check $? "a first job is accepted"
post "$small"
[ "$(cat "$work/status")" = 202 ]; check $? "a second job is accepted"
id2=$(jq -r .id "$work/out")
post "$small"
[ "$(cat "$work/status")" = 429 ] && grep -q 'too-many-jobs' "$work/out"
check $? "a third job in flight is refused with 429 (max_jobs_in_flight 2)"
bcurl -s -X POST "$url/v1/jobs/$id2/cancel" >/dev/null
upload=$(head -c 2000 /dev/zero | base64 -w0)
post "{\"scene\": {\"mesh\": {\"generate\": \"box\", \"cells\": [2, 1, 1], \"size\": [2, 1, 1]}, \"material\": {\"mu\": 1, \"lambda\": 1}, \"handles\": [{\"select\": {\"box\": {\"min\": [0, 0, 0], \"max\": [0, 1, 1]}}}]}, \"files\": [{\"name\": \"pad.txt\", \"base64\": \"$upload\"}]}"
[ "$(cat "$work/status")" = 202 ]; check $? "a job uploading 2,000 bytes is accepted (quota 3,000)"
id3=$(jq -r .id "$work/out")
bcurl -s -X POST "$url/v1/jobs/$id3/cancel" >/dev/null
post "{\"scene\": {\"mesh\": {\"generate\": \"box\", \"cells\": [2, 1, 1], \"size\": [2, 1, 1]}, \"material\": {\"mu\": 1, \"lambda\": 1}, \"handles\": [{\"select\": {\"box\": {\"min\": [0, 0, 0], \"max\": [0, 1, 1]}}}]}, \"files\": [{\"name\": \"pad.txt\", \"base64\": \"$upload\"}]}"
[ "$(cat "$work/status")" = 413 ] && grep -q 'storage-quota' "$work/out"
check $? "another 2,000 bytes over the 3,000-byte quota are refused with 413"
code=$(bcurl -s -o /dev/null -w '%{http_code}' -X DELETE "$url/v1/jobs/$id3")
[ "$code" = 204 ]; check $? "an ended job is deleted (204)"
post "{\"scene\": {\"mesh\": {\"generate\": \"box\", \"cells\": [2, 1, 1], \"size\": [2, 1, 1]}, \"material\": {\"mu\": 1, \"lambda\": 1}, \"handles\": [{\"select\": {\"box\": {\"min\": [0, 0, 0], \"max\": [0, 1, 1]}}}]}, \"files\": [{\"name\": \"pad.txt\", \"base64\": \"$upload\"}]}"
[ "$(cat "$work/status")" = 202 ]; check $? "and its bytes are free again"

"$slow" 127.0.0.1 "$port" 300 6 >"$work/slow.txt"
check $? "/healthz answers beside 300 half-sent requests ($(cat "$work/slow.txt"))"
"$slow" 127.0.0.1 "$port" 300 6 --idle >"$work/idle.txt"
check $? "/healthz answers beside 300 silent connections ($(cat "$work/idle.txt"))"

[ "$(stat -c %a "$work/state/broker.sqlite")" = 600 ]
check $? "the store is readable by its owner alone (mode $(stat -c %a "$work/state/broker.sqlite"))"
[ "$(stat -c %a "$work/state/jobs")" = 700 ]
check $? "so is the jobs' folder (mode $(stat -c %a "$work/state/jobs"))"

stop_broker "$work" b
check $? "the broker stops on SIGTERM"
exit $fail
