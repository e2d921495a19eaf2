#!/bin/sh
# grid_scenes.sh BIOTGRID AGENT_SCRIPTS WORKDIR GRID_CONFIG SCENES_DIR
# Every shipped scene (SCENES_DIR/*.json, static and dynamic) on one local
# grid under each mechanism: `grid up` (ephemeral loopback ports), each
# scene submitted with `biotgrid submit` (its mesh files uploaded) under
# central, catallactic and posted, as many jobs at once as the grid has
# sparse-solve slots (the large-mesh scenes alone, see alone()); each job succeeds and its energy equals `biotgrid
# solve`'s on the same scene (1e-10 relative to the run's energy scale:
# the larger of the final energy, the starting energy and, for a morph,
# every frame's; a morph's every frame is compared too). Each report's
# market section has a money curve that rises monotonically to the money
# spent, and the job's files list the error-against-time-and-money SVG
# with both axis labels. `grid down` leaves no process.
#
# The suite runs under three builds (one with sanitizers on two cores), so
# the slow scenes run with an override, applied identically to the scene
# given to `solve` and to `submit`, printed for each scene below: fewer
# steps or frames, or an iteration cap (a capped run still compares the
# same iterates). No scene is left out.
set -u
bin=$1 scripts=$2 work=$3 config=$4 scenes=$5
here=$(cd "$(dirname "$0")" && pwd)
. "$here/broker_lib.sh"
grid_test_begin "$bin" "$work"
mkdir -p "$work/scenes" "$work/local" "$work/jobs"
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

# The scenes on the 34,055-tetrahedron bunny and the 22,704-triangle
# camel head run alone: an agent answers the market only between service
# calls, so one job's multi-second factorization on the sparse-solve agent
# makes another job's purchase miss the market's 10 s buy timeout on a
# loaded two-core host.
alone() {
  case $1 in bunny-drop|bunny-edit|inverted-bunny|lion-head-param) return 0 ;; esac
  return 1
}

# The override of a scene (a jq filter), "." for none.
override() {
  case $1 in
    bar-morph) echo '.task.frames = 3' ;;
    bar-spin) echo '.task.steps = 60' ;;
    beam-cantilever) echo '.task.steps = 30' ;;
    bunny-drop) echo '.task.steps = 2 | .task.output_every = 1' ;;
    bunny-edit) echo '.solver.max_iterations = 3 | del(.reference)' ;;
    lion-head-param) echo '.solver.max_iterations = 4' ;;
    inverted-bunny) echo '.solver.max_iterations = 3' ;;
    stiff-bar) echo '.solver.max_iterations = 12' ;;
    *) echo '.' ;;
  esac
}

# A scene with an override is written to WORKDIR/scenes: its relative
# file references (mesh, morph target, selection files) become absolute
# so that it names the same files as the shipped one.
t_start=$(now)
list=""
for src in "$scenes"/*.json; do
  name=$(basename "$src" .json)
  filter=$(override "$name")
  how="with the other jobs"
  alone "$name" && how="alone"
  if [ "$filter" = . ]; then
    echo "scene $name: as shipped, $how"
  else
    echo "scene $name: override $filter, $how"
  fi
  # Every scene is copied: its relative file references become absolute.
  {
    dir=$(cd "$(dirname "$src")" && pwd)
    map='{}'
    for s in $(jq -r '[.. | strings] | unique | .[]' "$src" | grep -v '[[:space:]]'); do
      case $s in /*) continue ;; esac
      if [ -f "$dir/$s" ]; then
        map=$(jq -n --argjson m "$map" --arg k "$s" --arg v "$dir/$s" '$m + {($k): $v}')
      fi
    done
    jq --argjson m "$map" "walk(if type == \"string\" and \$m[.] then \$m[.] else . end) | $filter" \
      "$src" >"$work/scenes/$name.json"
    check $? "$name: the copy and its override apply"
  }
  list="$list $name"
done
[ -n "$list" ]; check $? "the shipped scenes are listed ($(echo $list | wc -w) scenes)"

# The reference: `biotgrid solve` on each scene, in process.
t0=$(now)
for name in $list; do
  t=$(now)
  "$bin" solve "$work/scenes/$name.json" --quiet --out "$work/local/$name" \
    >"$work/local/$name.log" 2>&1
  r=$?
  # An iteration cap of the override ends the run unconverged (exit 1).
  if [ $r -eq 1 ] && override "$name" | grep -q max_iterations &&
    jq -e '.runs[0].stop_reason == "iteration limit"' "$work/local/$name/report.json" \
      >/dev/null 2>&1; then
    r=0
  fi
  check $r "$name: biotgrid solve ($(since "$t") s)"
  [ $r -eq 0 ] || tail -3 "$work/local/$name.log" >&2
done
solve_seconds=$(since "$t0")

t0=$(now)
# The grid's host sells 4 cores and 16 GiB, so two jobs (2 cores each: a
# job's phases share its host's cores; 8 GiB at most) run at once on any
# machine: the test compares answers, not capacity.
jq '.host = {cores: 4, memory: 16}' "$config" >"$work/grid-config.json"
grid_up_market "$bin" "$work/grid-config.json" "$state"
# Free sparse-solve slots on the market (each job buys one).
free_solve() {
  bcurl -sf "$url/v1/agents" | jq '[.agents[] | select(.source == "market" and .alive and (.services | length) > 0 and
    (.services | index("sparse-solve")))] | map(.free_slots) | add // 0'
}
slots=$(free_solve)
[ "${slots:-0}" -ge 1 ]; check $? "the grid has $slots sparse-solve slots: that many jobs at once"

# Submits one job: prints its id.
submit() {
  "$bin" submit "$work/scenes/$1.json" --mechanism "$2" --budget 100 --json --broker "$url" \
    2>>"$work/jobs/submit.err" | jq -r '.id // empty'
}

# A job pool of $slots: a job is submitted when a slot is free on the
# market (a released slot reaches the directory a little after its job
# ends; after 30 s the job is submitted anyway, and a slot still held
# then fails it), and reaped when it ends.
queue=""
for name in $list; do
  for mech in central catallactic posted; do queue="$queue $name:$mech"; done
done
inflight=""
reap() {
  still=""
  for entry in $inflight; do
    id=${entry##*=}
    st=$(bcurl -sf "$url/v1/jobs/$id" | jq -r .state)
    case $st in
      succeeded|failed|cancelled)
        echo "${entry%%=*} $st $(since "$(cat "$work/jobs/$id.t0")") s" >>"$work/jobs/ended.txt"
        echo "$st" >"$work/jobs/$id.state" ;;
      *) still="$still $entry" ;;
    esac
  done
  inflight=$still
}
deadline=$(($(date +%s) + 1500))
for job in $queue; do
  name=${job%%:*} mech=${job##*:}
  limit=$slots
  alone "$name" && limit=1
  waited=0
  while :; do
    reap
    n=$(echo $inflight | wc -w)
    # A job that runs alone waits for the pool to drain, and blocks it.
    for entry in $inflight; do alone "${entry%%:*}" && n=$slots; done
    if [ "$n" -lt "$limit" ]; then
      [ "$(free_solve)" -ge $((slots - n)) ] && break
      waited=$((waited + 1))
      if [ $waited -ge 300 ]; then
        echo "note: $(free_solve) of $slots sparse-solve slots free with $n jobs running" >&2
        break
      fi
    fi
    [ "$(date +%s)" -lt "$deadline" ] || break
    sleep 0.1
  done
  now >"$work/jobs/t0"
  id=$(submit "$name" "$mech")
  if [ -z "$id" ]; then
    check 1 "$name/$mech: submitted"
    continue
  fi
  mv "$work/jobs/t0" "$work/jobs/$id.t0"
  echo "$name $mech $id" >>"$work/jobs/ids.txt"
  inflight="$inflight $job=$id"
done
while [ -n "$inflight" ] && [ "$(date +%s)" -lt "$deadline" ]; do
  reap
  sleep 0.1
done
[ -z "$inflight" ]; check $? "every job ended within the deadline"
grid_seconds=$(since "$t0")
cat "$work/jobs/ended.txt"

while read -r name mech id; do
  st=$(cat "$work/jobs/$id.state" 2>/dev/null || echo unknown)
  [ "$st" = succeeded ]; check $? "$name/$mech: the job succeeded (got $st)"
  if [ "$st" != succeeded ]; then
    bcurl -sf "$url/v1/jobs/$id" | jq -c '{state, reason}' >&2
    continue
  fi
  rep="$work/jobs/$id.json"
  bcurl -sf "$url/v1/jobs/$id/result/report.json" >"$rep"
  loc="$work/local/$name/report.json"
  jq -n --slurpfile a "$rep" --slurpfile b "$loc" '
    $a[0].runs[0] as $x | $b[0].runs[0] as $y |
    ([($y.energy | fabs), ($y.trace[0].energy // 0 | fabs)] +
     [($b[0].frames // $y.frames // [])[] | .energy | fabs] | max) as $scale |
    (($x.energy - $y.energy) | fabs) <= 1e-10 * $scale and
    ([($x.frames // [])[] | .energy] | length) == ([($y.frames // [])[] | .energy] | length) and
    ([range(0; ($y.frames // []) | length) as $k |
      (($x.frames[$k].energy - $y.frames[$k].energy) | fabs) <= 1e-10 * $scale] | all)' |
    grep -q true
  check $? "$name/$mech: energy $(jq .runs[0].energy "$rep") equals biotgrid solve's $(jq .runs[0].energy "$loc") (1e-10 relative)"
  jq -e '.market as $m | $m.error_vs_time_and_money as $c | ($c | length) > 0 and
         ([range(1; $c | length) as $k | $c[$k].money >= $c[$k - 1].money] | all) and
         $c[0].money >= 0 and
         (($c[-1].money - $m.spent) | fabs) <= 1e-9 * $m.spent and $m.spent > 0' "$rep" >/dev/null
  check $? "$name/$mech: the money curve rises monotonically to the money spent ($(jq .market.spent "$rep"))"
  svg="$work/jobs/$id.svg"
  bcurl -sf "$url/v1/jobs/$id/result" | jq -e '[.. | strings] | index("error-vs-time-and-money.svg")' \
    >/dev/null &&
    bcurl -sf "$url/v1/jobs/$id/result/error-vs-time-and-money.svg" >"$svg" &&
    head -c 5 "$svg" | grep -q '^<svg ' && tail -1 "$svg" | grep -q '^</svg>$' &&
    [ "$(grep -c '<svg ' "$svg")" -eq 3 ] && [ "$(grep -c '</svg>' "$svg")" -eq 3 ] &&
    grep -q '>wall time (s)</text>' "$svg" &&
    grep -q '>money spent (pro-rated by service time)</text>' "$svg"
  check $? "$name/$mech: the result lists error-vs-time-and-money.svg, two panels with both axis labels"
done <"$work/jobs/ids.txt"
[ "$(wc -l <"$work/jobs/ids.txt")" -eq "$(echo $queue | wc -w)" ]
check $? "every scene was submitted under every mechanism ($(echo $queue | wc -w) jobs)"

grid_test_end "$scripts"
echo "timing: solve (all scenes, in process) ${solve_seconds} s; grid up to last job ${grid_seconds} s; total $(since "$t_start") s"
exit $fail
