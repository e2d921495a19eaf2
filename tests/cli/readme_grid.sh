#!/bin/sh
# readme_grid.sh BIOTGRID GRID_CONFIG SCENE WORKDIR NO_AGENTS_LEFT
# The README's first command after the install — grid up, submit the
# default scene through REST and wait for its result, grid down — on the
# default grid config, with the broker on ephemeral loopback ports and the
# state in WORKDIR (the only changes from the README's line). It must exit
# 0, leave the result's report with a converged run, print the job's
# contracts, and leave no process of the grid behind.
set -u
bin=$1 config=$2 scene=$3 work=$4 no_left=$5
rm -rf "$work"
mkdir -p "$work"
state="$work/grid"
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
trap '"$bin" grid down --state "$state" >/dev/null 2>&1; exit 1' INT TERM

BIOTGRID_GRID_DIR=$state
export BIOTGRID_GRID_DIR
"$bin" grid up "$config" --state "$state" --broker-port 0 \
    --broker-endpoint 'tcp://127.0.0.1:*' >"$work/up.txt" 2>&1 &&
    { timeout 200 "$bin" submit "$scene" --out "$work/first-job" >"$work/submit.txt" 2>&1; s=$?
      if [ $s -eq 124 ]; then
        # A job of two seconds that is not done in 200: show where it
        # stands before the grid goes down (ctest's own timeout would kill
        # this script and leave the grid running).
        echo "FAIL: submit did not finish within 200 s; the broker's view:"
        url=$(jq -r '.broker.url // empty' "$state/grid.json" 2>/dev/null)
        auth="Authorization: Bearer $(head -1 "$state/token" 2>/dev/null)"
        curl -s -H "$auth" "$url/v1/jobs" | jq -c '.jobs[] | {id, state}' 2>/dev/null
        curl -s -H "$auth" "$url/v1/agents" | jq -c '.agents[] | {name, alive, free_slots}' 2>/dev/null
        tail -n 40 "$state/broker.log" 2>/dev/null
      fi
      "$bin" grid down --state "$state" >"$work/down.txt" 2>&1 && [ $s -eq 0 ]; }
rc=$?
cat "$work/up.txt" "$work/submit.txt" "$work/down.txt" 2>/dev/null
[ $rc -eq 0 ] || fail "the README's first command exited $rc"
grep -Eq "^job j[0-9a-f]{16}: succeeded" "$work/submit.txt" || fail "no 'succeeded' line"
grep -q "report\\.json (" "$work/submit.txt" || fail "the result's files were not listed"
grep -Eq "^job j[0-9a-f]{16}: contract: rotation-fit from agent rotfit-[12], price " "$work/submit.txt" ||
    fail "no rotation-fit contract shown"
grep -Eq "^job j[0-9a-f]{16}: contract: sparse-solve from agent solve-1, price " "$work/submit.txt" ||
    fail "no sparse-solve contract shown"
grep -q "contract: integration-step" "$work/submit.txt" && fail "a static job bought an integration step"
grep -Eq "^job j[0-9a-f]{16}: resource contract: [0-9.]+ cores? from agent [a-z0-9-]+, price [0-9.e+-]+ per core-second$" \
    "$work/submit.txt" || fail "the cores bought for the job's services are not shown as such"
grep -Eq "^  spent [0-9.e+]+ of budget 1000 \\(central, 3 contracts\\)" "$work/submit.txt" ||
    fail "the money spent against the budget is not shown"
[ "$(grep -c "succeeded" "$work/submit.txt")" -eq 1 ] || fail "'succeeded' is not printed once"
grep -q '[{}]' "$work/submit.txt" && fail "raw JSON in submit's plain lines"
[ "$(jq -r '.runs[0].converged' "$work/first-job/report.json" 2>/dev/null)" = true ] ||
    fail "report.json has no converged run"
[ "$(jq -r '.market.mechanism' "$work/first-job/report.json" 2>/dev/null)" != null ] ||
    fail "report.json has no market section"
sh "$no_left" "$state" || fail "a process of the grid is left"
exit $fails
