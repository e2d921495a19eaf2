#!/bin/sh
# market_config.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE
# The broker's `market` settings. A broker config whose market object has
# a value out of range, a wrong type or an unknown key is refused with exit
# 2 naming the field, before anything listens; so is a grid config's
# broker.market, by `grid up`, before any process starts. The k of the
# central clearing reaches it: clearings.csv records it, and each central
# service row's price is its clearing's, explained there by the orders
# that set it (a lone job: nobody left out, so the seller's ask).
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"

# A broker config that names its store and ports, with this market object.
broker_config() {
  jq -n --arg dir "$work/store-$1" --argjson market "$2" \
    '{port: 0, endpoint: "tcp://127.0.0.1:*", state_dir: $dir, market: $market}' >"$work/$1.json"
}
refused() {
  name=$1 market=$2 field=$3
  broker_config "$name" "$market"
  "$bin" broker --config "$work/$name.json" >"$work/$name.out" 2>&1 </dev/null
  rc=$?
  [ "$rc" -eq 2 ] && grep -q "$field" "$work/$name.out" && ! [ -e "$work/store-$name" ]
  check $? "broker market $market: exit 2 naming $field, no store made (exit $rc: $(head -c 200 "$work/$name.out"))"
}
refused k-range '{"k": 2}' 'market.k'
refused k-type '{"k": "half"}' 'market.k'
refused period-zero '{"period": 0}' 'market.period'
refused hops-range '{"hops": 17}' 'market.hops'
refused degree-range '{"overlay_degree": 9}' 'market.overlay_degree'
refused rounds-fraction '{"max_rounds": 2.5}' 'market.max_rounds'
refused unknown-key '{"auction": "dutch"}' 'auction'
refused not-object '[1]' 'market'

# grid up refuses a bad broker.market before it starts a process.
jq '.broker.market = {"reply_timeout": -1}' "$config" >"$work/bad-grid.json"
"$bin" grid up "$work/bad-grid.json" --state "$work/bad-state" --broker-port 0 \
  --broker-endpoint 'tcp://127.0.0.1:*' >"$work/bad-grid.out" 2>&1
rc=$?
[ "$rc" -eq 2 ] && grep -q 'market.reply_timeout' "$work/bad-grid.out" &&
  ! [ -e "$work/bad-state/grid.json" ]
check $? "grid up with broker.market.reply_timeout -1: exit 2 naming it, nothing started (exit $rc)"
sh "$scripts/no_agents_left.sh" "$work/bad-state"
check $? "no process of the refused grid is left"

# The broker's other settings pass through a grid config, checked first as
# the broker reads them: a wrong one refused by name, nothing started.
for bad in '{"stop_grace_ms": -5}:stop_grace_ms' '{"agent_recovery": 1}:agent_recovery' \
  '{"max_elements": "many"}:max_elements'; do
  obj=${bad%:*} field=${bad##*:}
  rm -rf "$work/bad-state"
  jq --argjson o "$obj" '.broker += $o' "$config" >"$work/bad-grid.json"
  "$bin" grid up "$work/bad-grid.json" --state "$work/bad-state" --broker-port 0 \
    --broker-endpoint 'tcp://127.0.0.1:*' >"$work/bad-grid.out" 2>&1
  rc=$?
  [ "$rc" -eq 2 ] && grep -q "broker: $field\|broker.$field" "$work/bad-grid.out" &&
    ! [ -e "$work/bad-state/grid.json" ]
  check $? "grid up with broker $obj: exit 2 naming $field, nothing started (exit $rc: $(head -c 200 "$work/bad-grid.out"))"
done

# The clearing price. In this grid every service agent has one slot and
# every service good as many sellers as the job has units of it, so every
# ask is matched and neither an unsold slot nor a bid left out bounds the
# interval: the old k-pricing put the price at the buyer's limit at k = 1
# and between it and the ask at k = 0.5. Now nobody is left out, so each
# service row is priced at the sellers' ask whatever k is, and its
# clearing (clearings.csv) says so: rule "ask", price = low, set by a
# matched seller's ask, high by the job's own bid; k is recorded as
# configured. Layer 1 is not checked here: the host's one
# resource seller is priced by the same rule.
for k in 1 0; do
  jq --argjson k "$k" '.broker.market = {"k": $k, "period": 0.1} | .agents |= map(.slots = 1)' \
    "$config" >"$work/k$k-grid.json"
  grid_up_market "$bin" "$work/k$k-grid.json" "$state"
  jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "central", budget: 100}' >"$work/submit.json"
  id=$(bcurl -X POST -H 'Content-Type: application/json' --data-binary @"$work/submit.json" \
    "$url/v1/jobs" | jq -r .id)
  st=$(wait_job "$url" "$id" 300)
  [ "$st" = succeeded ]; check $? "central job at k = $k succeeded (got $st)"
  bcurl "$url/v1/market/contracts.csv" >"$work/contracts-k$k.csv"
  bcurl "$url/v1/market/clearings.csv" >"$work/clearings-k$k.csv"
  rows=$(awk -F, 'NR > 1 && $3 == "central" && $4 == "service"' "$work/contracts-k$k.csv" | wc -l)
  # Each central service row joined with its clearing (contracts.csv's
  # last column): the same price, the ask rule, k as configured, lo set
  # by a seller's matched ask, hi by the job's bid.
  off=$(awk -F, -v k="$k" 'FNR == 1 { next }
          FILENAME ~ /clearings/ { c[$1] = $0; next }
          $3 == "central" && $4 == "service" {
            if (!($17 in c)) { n++; next }
            split(c[$17], x, ",")
            p = $13; d = p - x[8]; if (d < 0) d = -d
            if (d > 1e-9 * p || x[7] != "ask" || x[6] + 0 != k || x[9] != x[8] ||
                x[10] != "matched ask" || x[11] !~ /^agent:[0-9]+$/ ||
                x[13] != "matched bid" || x[14] != "job:" $9) n++
          } END { print n + 0 }' "$work/clearings-k$k.csv" "$work/contracts-k$k.csv")
  [ "$rows" -ge 3 ] && [ "$off" -eq 0 ]
  check $? "k = $k: each of the $rows central service rows is priced by its clearing at its seller's ask, k recorded ($off are not)"
  "$bin" grid down --state "$state" >"$work/down-k$k.txt" 2>&1
  check $? "grid down (k = $k)"
done
grid_test_end "$scripts"
exit $fail
