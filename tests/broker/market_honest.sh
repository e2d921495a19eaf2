#!/bin/sh
# market_honest.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE LONG_SCENE MARKET_AUDIT
# The live market prices honestly (issue 28), on a local grid (`grid up`,
# ephemeral loopback ports) whose agents have one slot each, so every
# seller a job buys from sells its last free slot:
#  - equal jobs on an idle grid pay alike: the same SCENE, budget 1000,
#    submitted one after another, three times under each mechanism; under
#    each, the most a job spent is at most twice the least, and a central
#    job spends at most twice what a posted one does (with one free slot a
#    seller's book had nothing left out, and k-pricing charged a central
#    job half its budget share, ~100 times the ask, every time);
#  - every central service row's price is its clearing's (clearings.csv),
#    the seller's ask, explained there by the orders that set it;
#  - reconciled on completion: the moment a job reads succeeded, the
#    exported log (contracts.csv, agents.csv) passes the simulator's audit
#    (MARKET_AUDIT --live) with jobs paying for what they can hold within
#    5 % (--paid-ratio 0.05), and none of the job's rows is open;
#  - cancelled while running (LONG_SCENE, many steps): the moment the
#    cancel has answered, the job's rows are closed and the log passes the
#    same audit.
# `grid down` leaves no process.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5 long=$6 audit=$7
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
jq '.agents |= map(.slots = 1) | .broker.market = {"period": 0.1}' "$config" >"$work/grid.json"
grid_up_market "$bin" "$work/grid.json" "$state"

# export DIR: the market's log as it is now, into DIR.
export_log() {
  mkdir -p "$1"
  bcurl "$url/v1/market/contracts.csv" >"$1/contracts.csv" &&
    bcurl "$url/v1/market/agents.csv" >"$1/agents.csv"
}
# closed DIR JOB: none of JOB's rows is open (an open row ends 1e9 s on).
closed() {
  awk -F, -v job="$2" 'NR > 1 && $4 == "service" && $9 == job { mine[$5] = 1 }
    NR > 1 && ($5 in mine) && $8 - $7 > 1e8 { n++ } END { exit n > 0 }' "$1/contracts.csv"
}

for mech in central posted catallactic; do
  jq -n --slurpfile s "$scene" --arg m "$mech" '{scene: $s[0], mechanism: $m, budget: 1000}' \
    >"$work/submit-$mech.json"
  for n in 1 2 3; do
    id=$(bcurl -X POST -H 'Content-Type: application/json' --data-binary @"$work/submit-$mech.json" \
      "$url/v1/jobs" | jq -r .id)
    st=$(wait_job "$url" "$id" 300)
    dir="$work/at-end-$mech-$n"
    export_log "$dir"
    [ "$st" = succeeded ]; check $? "$mech job $n succeeded (got $st)"
    closed "$dir" "$id"; check $? "$mech job $n: its rows are closed when it reads succeeded"
    "$audit" --live --paid-ratio 0.05 "$dir" >"$dir/audit.txt" 2>&1
    check $? "$mech job $n: the log at that moment passes the audit, paid/holdable within 5 % ($(tr "\n" " " <"$dir/audit.txt"))"
    bcurl "$url/v1/jobs/$id" |
      jq '[.contracts[] | select(.service != "cores" and .service != "memory") |
           .price * .quantity] | add' >>"$work/spent-$mech.txt"
  done
  spread=$(sort -g "$work/spent-$mech.txt" | awk 'NR == 1 { lo = $1 } { hi = $1 } END { print hi / lo }')
  awk -v s="$spread" 'BEGIN { exit !(s <= 2) }'
  check $? "$mech: equal jobs spend within a factor 2 ($(tr '\n' ' ' <"$work/spent-$mech.txt"); most/least $spread)"
done
mean() { awk '{ s += $1 } END { print s / NR }' "$1"; }
central=$(mean "$work/spent-central.txt") posted=$(mean "$work/spent-posted.txt")
awk -v c="$central" -v p="$posted" 'BEGIN { exit !(c <= 2 * p && p <= 2 * c) }'
check $? "central and posted jobs spend within a factor 2 ($central, $posted)"

bcurl "$url/v1/market/clearings.csv" >"$work/clearings.csv"
export_log "$work/log"
# Each central service row with its clearing (contracts.csv's last
# column): the same price, the ask rule (nobody left out), price = low.
off=$(awk -F, 'FNR == 1 { next }
        FILENAME ~ /clearings/ { c[$1] = $0; next }
        $3 == "central" && $4 == "service" {
          rows++
          if (!($17 in c)) { n++; next }
          split(c[$17], x, ",")
          d = $13 - x[8]; if (d < 0) d = -d
          if (d > 1e-9 * $13 || x[7] != "ask" || x[9] != x[8] || x[10] != "matched ask") n++
        } END { print rows + 0, n + 0 }' "$work/clearings.csv" "$work/log/contracts.csv")
[ "${off% *}" -ge 9 ] && [ "${off#* }" -eq 0 ]
check $? "every central service row is priced by its clearing, at the sellers' ask (rows, off: $off)"

# Cancelled while running: settled before the cancel answers.
jq -n --slurpfile s "$long" '{scene: ($s[0] | .task.steps = 100000), mechanism: "central",
  budget: 1000}' >"$work/submit-long.json"
id=$(bcurl -X POST -H 'Content-Type: application/json' --data-binary @"$work/submit-long.json" \
  "$url/v1/jobs" | jq -r .id)
i=0 st=none
while [ $i -lt 600 ]; do
  st=$(bcurl "$url/v1/jobs/$id" | jq -r .state)
  [ "$st" = running ] && break
  sleep 0.1
  i=$((i + 1))
done
[ "$st" = running ]; check $? "the long job runs (got $st)"
sleep 1
st=$(bcurl -X POST "$url/v1/jobs/$id/cancel" | jq -r .state)
export_log "$work/at-cancel"
[ "$st" = cancelled ]; check $? "the cancel answers cancelled (got $st)"
closed "$work/at-cancel" "$id"; check $? "the cancelled job's rows are closed when the cancel answers"
"$audit" --live --paid-ratio 0.05 "$work/at-cancel" >"$work/at-cancel/audit.txt" 2>&1
check $? "the log at that moment passes the audit ($(tr "\n" " " <"$work/at-cancel/audit.txt"))"

grid_test_end "$scripts"
exit $fail
