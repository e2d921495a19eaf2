#!/bin/sh
# Runs each libFuzzer harness of a BIOTGRID_FUZZ=ON build for SECONDS and
# prints, per harness, the executions, the crashes and the machine's load
# as a Markdown table (tests/fuzz/README.md).
#
#   tests/fuzz/run.sh SECONDS [NAME...]      (default: every harness)
#
# FUZZ_BIN      the folder of the fuzz_NAME executables (default: build-fuzz/tests/fuzz)
# FUZZ_WORK     where the grown corpora and crash files go (default: $FUZZ_BIN/work)
# FUZZ_WORKERS  libFuzzer processes per harness (-fork=N), 1 by default
# FUZZ_RUNS     stop a harness after this many executions if it gets there
#               before SECONDS (-runs=N; one process only)
#
# Each input may take 10 s and one allocation 64 MB at most: inputs are
# a few KB, so anything more is a hang or an allocation the input does not
# justify, and is reported (timeout-*, oom-*) like a crash.
#
# The checked-in corpus (tests/fuzz/corpus/NAME) is read, never written:
# new inputs go to $FUZZ_WORK/NAME/corpus, crashes to $FUZZ_WORK/NAME/ as
# crash-*, leak-*, timeout-*, oom-*. A crash file that is kept belongs in
# corpus/NAME as a regression seed once the bug is fixed. Exits 1 when any
# harness crashed.
set -u
here=$(cd "$(dirname "$0")" && pwd)
seconds=${1:?usage: run.sh SECONDS [NAME...]}
shift
bin=${FUZZ_BIN:-$here/../../build-fuzz/tests/fuzz}
work=${FUZZ_WORK:-$bin/work}
workers=${FUZZ_WORKERS:-1}
names=$*
if [ -z "$names" ]; then
    names=$(cd "$here/corpus" && ls)
fi
load() { cut -d' ' -f1 /proc/loadavg; }
failed=0
rows=""
for name in $names; do
    exe=$bin/fuzz_$name
    if [ ! -x "$exe" ]; then
        echo "run.sh: no fuzzer $exe (build with -DBIOTGRID_FUZZ=ON)" >&2
        exit 2
    fi
    dir=$work/$name
    mkdir -p "$dir/corpus"
    log=$dir/fuzz.log
    before=$(load)
    start=$(date +%s)
    fork=""
    [ "$workers" -gt 1 ] && fork="-fork=$workers -ignore_crashes=1"
    runs=""
    [ -n "${FUZZ_RUNS:-}" ] && [ -z "$fork" ] && runs="-runs=$FUZZ_RUNS"
    # shellcheck disable=SC2086
    (cd "$dir" && "$exe" -max_total_time="$seconds" -print_final_stats=1 -timeout=10 \
        -rss_limit_mb=2048 -malloc_limit_mb=64 -artifact_prefix="$dir/" $fork $runs \
        "$dir/corpus" "$here/corpus/$name" >"$log" 2>&1)
    after=$(load)
    took=$(($(date +%s) - start))
    # One process: its final stats; -fork: the last status line's count.
    execs=$(grep 'stat::number_of_executed_units' "$log" | awk '{s += $2} END {print s + 0}')
    if [ -n "$fork" ]; then
        execs=$(grep -o '^#[0-9]*' "$log" | tail -1 | tr -d '#')
    fi
    crashes=$(find "$dir" -maxdepth 1 \( -name 'crash-*' -o -name 'leak-*' -o -name 'timeout-*' \
        -o -name 'oom-*' \) | wc -l)
    [ "$crashes" -gt 0 ] && failed=1
    rows="$rows| $name | $took | ${execs:-0} | $crashes | $before → $after |
"
    echo "fuzz_$name: ${execs:-0} executions, $crashes crashes (log: $log)" >&2
done
echo "| harness | seconds | executions | crashes | load (1 min, before → after) |"
echo "| --- | ---: | ---: | ---: | --- |"
printf '%s' "$rows"
exit $failed
