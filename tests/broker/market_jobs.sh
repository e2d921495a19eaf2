#!/bin/sh
# market_jobs.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE DYNAMIC_SCENE MARKET_AUDIT
#                OPENAPI_CHECK
# The live market end to end: `grid up` starts a broker and agents that
# register on it with --broker (ephemeral loopback ports). The scene is
# submitted under each mechanism; each job succeeds with `biotgrid
# solve`'s energy (1e-10 relative), its contracts (events and report) list
# rotation-fit and sparse-solve and no integration-step (a static scene).
# A budget under the sellers' floors fails with a reason naming the
# budget; contracts.csv has one row per contract, each price within both
# limits. A dynamic scene's plan lists integration-step: its job buys one.
# Both layers are live: each job's contracts include, for each service
# seller, the cores it bought on layer 1 (a resource row whose buyer is that
# seller); agents.csv lists the resource sellers; the simulator's audit
# (MARKET_AUDIT --live) passes on GET /v1/market/contracts.csv and agents.csv;
# the service rows' buyer is the job's id. Once the jobs have run, every
# JSON answer the grid gives (jobs, a job, its result, agents, market,
# health, a 404) conforms, nested items included, to the schema the
# broker's own GET /openapi.json documents for it (OPENAPI_CHECK).
# `grid down` leaves no process.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5 dynamic=$6 audit=$7 oas=$8
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
# The data lines of a server-sent event log's "contract" events.
contracts() { awk '/^event: / { e = $2 } /^data: / && e == "contract" { print }' "$1"; }
grid_up_market "$bin" "$config" "$state"

"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1
check $? "biotgrid solve (the reference)"
total=0 jobs_ids=""
for mech in central catallactic posted; do
  jq -n --slurpfile s "$scene" --arg m "$mech" '{scene: $s[0], mechanism: $m, budget: 100}' \
    >"$work/submit-$mech.json"
  id=$(submit_job "$url" "$work/submit-$mech.json")
  st=$(wait_job "$url" "$id" 300)
  [ "$st" = succeeded ]; check $? "$mech: the job succeeded (got $st)"
  [ "$st" = succeeded ] || bcurl -sf "$url/v1/jobs/$id" >&2
  bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report-$mech.json"
  same_energy "$work/report-$mech.json" "$work/local/report.json"
  check $? "$mech: its energy equals biotgrid solve's (1e-10 relative)"
  jq -e '[.market.contracts[].service] as $s | ($s | index("rotation-fit")) != null and
         ($s | index("sparse-solve")) != null and ($s | index("integration-step")) == null' \
    "$work/report-$mech.json" >/dev/null
  check $? "$mech: the report's contracts list rotation-fit and sparse-solve, no integration-step"
  jq -e --arg m "$mech" '.market.market == "live" and .market.mechanism == $m and
         .market.spent > 0 and .market.spent <= .market.budget' "$work/report-$mech.json" >/dev/null
  check $? "$mech: the report's market section (live, mechanism, 0 < spent <= budget)"
  bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events-$mech.txt"
  contracts "$work/events-$mech.txt" >"$work/contracts-$mech.txt"
  n=$(wc -l <"$work/contracts-$mech.txt")
  [ "$n" -gt 0 ] && grep -q '"service":"rotation-fit"' "$work/contracts-$mech.txt" &&
    grep -q '"service":"sparse-solve"' "$work/contracts-$mech.txt" &&
    ! grep -q '"service":"integration-step"' "$work/contracts-$mech.txt"
  check $? "$mech: the job's $n contract events list rotation-fit and sparse-solve only"
  jobs_ids="$jobs_ids $id"
  svc=$(grep -c -E '"service":"(rotation-fit|sparse-solve)"' "$work/contracts-$mech.txt")
  cores=$(grep -c '"service":"cores"' "$work/contracts-$mech.txt")
  [ "$svc" -gt 0 ] && [ "$cores" -eq "$svc" ]
  check $? "$mech: the job's contracts include one layer-1 cores row per service seller ($cores, $svc)"
  bcurl -sf "$url/v1/jobs/$id" | jq -e --argjson n "$n" '(.contracts | length) == $n and
      all(.contracts[]; (.agent | type) == "string" and .price >= .seller_limit and
          .price <= .buyer_limit)' >/dev/null
  check $? "$mech: GET /v1/jobs/{id} lists its $n contracts, each price within both limits"
  total=$((total + n))
done

jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 0.001}' \
  >"$work/submit-poor.json"
id=$(bcurl -sf -X POST -H 'Content-Type: application/json' --data-binary @"$work/submit-poor.json" \
  "$url/v1/jobs" | jq -r .id)
st=$(wait_job "$url" "$id" 60)
reason=$(bcurl -sf "$url/v1/jobs/$id" | jq -r .reason)
[ "$st" = failed ]; check $? "a budget of 0.001 fails the job (got $st)"
case $reason in *budget*) r=0 ;; *) r=1 ;; esac
check $r "its reason names the budget ($reason)"
bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events-poor.txt"
[ "$(contracts "$work/events-poor.txt" | wc -l)" -eq 0 ]; check $? "the poor job made no contract"

jq -n --slurpfile s "$dynamic" '{scene: $s[0], mechanism: "central", budget: 100}' \
  >"$work/submit-dynamic.json"
id=$(bcurl -sf -X POST -H 'Content-Type: application/json' \
  --data-binary @"$work/submit-dynamic.json" "$url/v1/jobs" | jq -r .id)
st=$(wait_job "$url" "$id" 300)
[ "$st" = succeeded ]; check $? "the dynamic scene's job succeeded (got $st)"
bcurl -sf --max-time 10 "$url/v1/jobs/$id/events" >"$work/events-dynamic.txt"
contracts "$work/events-dynamic.txt" >"$work/contracts-dynamic.txt"
grep -q '"service":"integration-step"' "$work/contracts-dynamic.txt"
check $? "the dynamic scene's job bought integration-step"
total=$((total + $(wc -l <"$work/contracts-dynamic.txt")))

# A job's contracts are released a little after it ends: until then a row
# is open (its end is the lease's, ~1e9 s on). Read the log once every row
# is closed (10 s at most), so it is final.
contracts_closed "$url" "$work/contracts.csv"
check $? "every contract is closed once the jobs have ended"
head -1 "$work/contracts.csv" | grep -q '^scenario,replication,mechanism,layer,request,'
check $? "contracts.csv has the simulator's header"
rows=$(($(wc -l <"$work/contracts.csv") - 1))
[ "$rows" -eq "$total" ]; check $? "contracts.csv has one row per contract ($rows rows, $total events)"
awk -F, 'NR > 1 { if (!($13 <= $14 + 1e-12 && $13 >= $15 - 1e-12)) bad++ }
         END { exit bad > 0 }' "$work/contracts.csv"
check $? "every contract's price lies within the buyer's and the seller's limits"
bcurl -sf "$url/v1/market" | jq -e '.market == "live" and (.prices | length) > 0' >/dev/null
check $? "/v1/market reports the live market's recent prices"
bcurl -sf "$url/v1/market/agents.csv" >"$work/agents.csv"
[ "$(($(wc -l <"$work/agents.csv") - 1))" -ge "$nagents" ]; check $? "agents.csv lists the agents"
# Layer 1: every service row's seller bought cores for the same request
# (buyer = that seller's id, seller a resource seller listed in agents.csv).
awk -F, 'FNR == 1 { next }
         FILENAME == ARGV[1] && $5 == "resource" && $6 == "cores" { res[$4] = 1; next }
         FILENAME == ARGV[1] { next }
         $4 == "service" { svc[$5] = $10; n++ }
         $4 == "resource" && $11 == "cores" { cores[$5 "|" $9] = $10 }
         END { if (n == 0) exit 1
               for (r in svc) { k = r "|" svc[r]; if (!(k in cores) || !(cores[k] in res)) exit 1 } }' \
  "$work/agents.csv" "$work/contracts.csv"
check $? "each service seller bought its cores from a resource seller on layer 1"
for jid in $jobs_ids; do
  grep -q ",service,[0-9]*,[^,]*,[^,]*,[^,]*,$jid," "$work/contracts.csv" || { r=1; break; }
  r=0
done
check $r "the service rows' buyer is the job's id"
"$audit" --live "$work" >"$work/audit.txt" 2>&1
check $? "the simulator's audit passes on the live log ($(cat "$work/audit.txt"))"

# The answers with real market data in them, against the served document.
bcurl -sf "$url/openapi.json" >"$work/openapi.json"
check $? "GET /openapi.json"
conforms() { # TEMPLATE PATH
  got=$(bcurl -s -o "$work/answer.json" -w '%{http_code} %{content_type}' "$url$2")
  code=${got%% *}
  "$oas" "$work/openapi.json" "$1" GET "$code" "${got#* }" <"$work/answer.json" 2>"$work/oas.txt"
  check $? "GET $2 ($code) conforms to the OpenAPI document $(cat "$work/oas.txt")"
}
conforms /v1/market /v1/market
conforms /v1/agents /v1/agents
conforms /v1/jobs /v1/jobs
conforms /healthz /healthz
conforms /v1/jobs/{id} /v1/jobs/j0000000000000000
for jid in $jobs_ids $id; do
  conforms /v1/jobs/{id} "/v1/jobs/$jid"
  conforms /v1/jobs/{id}/result "/v1/jobs/$jid/result"
done

grid_test_end "$scripts"
exit $fail
