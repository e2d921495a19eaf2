#!/bin/sh
# Instructions per durable REST submit, under callgrind: bench_rest
# instruments only its group-commit run (clients, server and store
# together), so the program total divided by that run's jobs is the
# instruction count of one submit end to end (kernel work is not counted:
# callgrind sees user space only). Prints the bench's own lines, the count,
# and the inclusive share of the main parts of the path.
#
#   bench_rest_callgrind.sh BENCH_REST [CLIENTS] [JOBS] [BENCH_REST OPTIONS...]
set -eu
bench=$1
clients=${2:-4}
jobs=${3:-400}
shift $(($# < 3 ? $# : 3))
jobs=$((jobs - jobs % clients))
out=$(mktemp -d /tmp/bench-rest-cg-XXXXXX)
trap 'rm -rf "$out"' EXIT INT TERM
valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file="$out/cg.out" \
    "$bench" --clients "$clients" --jobs "$jobs" "$@" >"$out/bench.txt" 2>"$out/valgrind.txt" || {
    cat "$out/bench.txt" "$out/valgrind.txt" >&2
    exit 1
}
cat "$out/bench.txt"
callgrind_annotate --inclusive=yes --threshold=100 "$out/cg.out" >"$out/annotate.txt"
awk -v jobs="$jobs" '
    /PROGRAM TOTALS/ { gsub(",", "", $1); total = $1;
                       printf "  callgrind: %d instructions per submit (user space, all threads)\n", total / jobs }
    # function lines: "1,234 (12.3%)  file:function [object]"
    total && $2 ~ /%\)$/ {
        n = $1; gsub(",", "", n);
        name = $3; sub(/.*:/, "", name);
        if (name ~ /^(submit_job|read_submission|bg_scene_parse_with|bgb_base64_decode|unpack|job_json|send_json|plan_json|cJSON_PrintUnformatted|cJSON_ParseWithLengthOpts|bgb_store_submit_at|write_batch|writer_main|sqlite3_prepare_v3|sqlite3_step|curl_easy_perform|malloc|free)$/ && !(name in seen)) {
            seen[name] = 1;
            printf "    %-28s %8d per submit (%s)\n", name, n / jobs, $2
        }
    }' "$out/annotate.txt"
