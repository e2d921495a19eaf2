#!/bin/sh
# live_vs_sim.sh BIOTGRID BENCH_ALLOC WORK [REPS]
# One small experiment run live and simulated with the same agents and
# demand (issue 28 item 5), each mechanism, REPS replications (default 5):
# - simulated: `biotgrid sim live_vs_sim.json` (its description says what
#   it models);
# - live: 8 agent daemons on loopback, each selling every service from 2
#   slots at floor 1 with margin 0.2 and no load slope (so asking 1.2 a
#   unit, as the simulated sellers' cost), the first selling the host's 32
#   cores and 128 GiB; bench_alloc's stream: jobs at 0.8 a second for 60 s,
#   3 units of rotation fit and 3 of sparse solve each, valuations 1.5-4.5
#   a unit, 30 s deadlines, held 9 s once bought (what 3 units of 3e9 flops
#   take at 1e9 flops/s in the simulation); seeds 28, 29, ...
# Prints a Markdown table: allocation rate (jobs allocated over requested;
# simulated: service items), price per unit of work and spend per job
# (simulated: per two items), mean ± the half-width of the 95 % Student-t
# interval over the replications. Every process started here is stopped.
# Not part of the test suite (several minutes).
set -u
BIOTGRID=$1 BENCH=$2 WORK=$3 REPS=${4:-5}
HERE=$(cd "$(dirname "$0")" && pwd)
rm -rf "$WORK" && mkdir -p "$WORK" || exit 1
PIDS=""
cleanup() {
    for p in $PIDS; do kill "$p" 2>/dev/null; done
    for p in $PIDS; do wait "$p" 2>/dev/null; done
}
trap cleanup EXIT INT TERM

sed "s/\"replications\": [0-9]*/\"replications\": $REPS/" "$HERE/live_vs_sim.json" >"$WORK/sim.json"
"$BIOTGRID" sim "$WORK/sim.json" --out "$WORK/sim" --jobs 2 --quiet || exit 1

"$BENCH" stream "$WORK" 8 28 0.8 60 9 "$REPS" >"$WORK/live.txt" 2>"$WORK/live.err" &
HOST=$!
PIDS=$HOST
i=0
while [ ! -s "$WORK/endpoint" ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
[ -s "$WORK/endpoint" ] || { echo "live_vs_sim: the stand-in did not start"; exit 1; }
EP=$(cat "$WORK/endpoint")
for k in 1 2 3 4 5 6 7 8; do
    OPENBLAS_NUM_THREADS=1 "$BIOTGRID" agent --name "a$k" --services all --slots 2 --broker "$EP" \
        --floor 1 --margin 0.2 --load-slope 0 --cores 32 --memory 128 >"$WORK/a$k.log" 2>&1 &
    PIDS="$PIDS $!"
done
wait "$HOST" || { echo "live_vs_sim: the live stream failed"; cat "$WORK/live.err"; exit 1; }
cleanup
PIDS=""

# MECHANISM METRIC VALUE lines, one per replication.
awk '$1 == "stream" { m = $2 == "posted" ? "baseline" : $2
       print "live", m, "rate", $10; print "live", m, "price", $12; print "live", m, "spend", $14 }' \
    "$WORK/live.txt" >"$WORK/values.txt"
awk -F, 'NR == FNR && FNR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
         NR == FNR { k = $col["mechanism"] "|" $col["replication"]
                     rate[k] = $col["allocation_rate"]; price[k] = $col["price_mean"]; next }
         FNR == 1 { next }
         $4 == "service" { k = $3 "|" $2; money[k] += $12 * $13; n[k]++ }
         END { for (k in rate) { split(k, x, "|")
                 print "sim", x[1], "rate", rate[k]; print "sim", x[1], "price", price[k]
                 if (n[k]) print "sim", x[1], "spend", money[k] / (n[k] / 2) } }' \
    "$WORK/sim/replications.csv" "$WORK/sim/contracts.csv" >>"$WORK/values.txt"
echo "| metric | mechanism | live (mean ± 95 % half-width) | simulated |"
echo "|---|---|---|---|"
awk 'BEGIN { split("12.706 4.303 3.182 2.776 2.571 2.447 2.365 2.306 2.262", t, " ") }
     { k = $2 "|" $3 "|" $1; n[k]++; s[k] += $4; q[k] += $4 * $4 }
     function cell(k,   m, v, h) {
         if (!n[k]) return "—"
         m = s[k] / n[k]
         if (n[k] < 2) return sprintf("%.4g (1 run)", m)
         v = (q[k] - n[k] * m * m) / (n[k] - 1); if (v < 0) v = 0
         h = (n[k] <= 10 ? t[n[k] - 1] : 1.96) * sqrt(v / n[k])
         return sprintf("%.4g ± %.2g", m, h) }
     END { split("rate price spend", ms, " "); split("central catallactic baseline", mech, " ")
           name["rate"] = "allocation rate"; name["price"] = "price per unit"
           name["spend"] = "spend per job"
           for (i = 1; i <= 3; i++) for (j = 1; j <= 3; j++) {
               k = mech[j] "|" ms[i]
               printf "| %s | %s | %s | %s |\n", name[ms[i]],
                      mech[j] == "baseline" ? "posted (baseline)" : mech[j],
                      cell(k "|live"), cell(k "|sim") } }' "$WORK/values.txt"
