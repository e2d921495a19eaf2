#!/bin/sh
# small_host.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENE
# A grid whose machine sells 1 core and 4 GiB ("host" in the grid config)
# still computes a job: the broker splits the rotation fit over no more
# agents than there are cores (one part here, where the shipped grid has
# two rotation-fit agents), each service's cores are capped at the host's
# one, and the nominal memory needs (1 GiB rotation fit, 4 sparse solve, 2
# integration step: 8 for a job with a two-part rotation fit) shrink in
# proportion to fit the 4 GiB, so the job is bought, runs, and gives
# `biotgrid solve`'s energy (1e-10 relative). `grid down` leaves no process.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scene=$5
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
jq '.host = {cores: 1, memory: 4}' "$config" >"$work/grid-config.json"
grid_up_market "$bin" "$work/grid-config.json" "$state"

"$bin" solve "$scene" --quiet --out "$work/local" >/dev/null 2>&1
check $? "biotgrid solve (the reference)"
jq -n --slurpfile s "$scene" '{scene: $s[0], mechanism: "posted", budget: 100}' >"$work/submit.json"
id=$(submit_job "$url" "$work/submit.json")
st=$(wait_job "$url" "$id" 300)
[ "$st" = succeeded ]; check $? "the job on a 1-core, 4 GiB host succeeded (got $st)"
[ "$st" = succeeded ] || bcurl -sf "$url/v1/jobs/$id" >&2
bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$work/report.json"
same_energy "$work/report.json" "$work/local/report.json"
check $? "its energy equals biotgrid solve's (1e-10 relative)"
bcurl -sf "$url/v1/market/contracts.csv" >"$work/contracts.csv"
# SERVICE,RESOURCE,USE per resource row (what it holds while its service
# runs), the service its request serves.
awk -F, 'NR > 1 && $4 == "service" { svc[$5] = $11 }
         NR > 1 && $4 == "resource" { row[++n] = $5 "," $11 "," $16 }
         END { for (i = 1; i <= n; i++) { split(row[i], r, ","); print svc[r[1]] "," r[2] "," r[3] } }' \
  "$work/contracts.csv" | sort >"$work/resources.txt"
cat "$work/resources.txt"
[ "$(awk -F, 'NR > 1 && $4 == "service" && $11 == "rotation-fit"' "$work/contracts.csv" | wc -l)" -eq 1 ]
check $? "the rotation fit was bought in one part (one core on the host)"
printf '%s\n' "rotation-fit,cores,1" "rotation-fit,memory,0.5" "sparse-solve,cores,1" \
  "sparse-solve,memory,2" | sort | cmp -s - "$work/resources.txt"
check $? "cores capped at the host's one, memory needs halved to fit 4 GiB"
grid_test_end "$scripts"
exit $fail
