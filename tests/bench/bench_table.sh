#!/bin/sh
# bench_table.sh — the solver-speed table (issue 29) in one command: every
# figure measured on a build before the change and on one after it, the
# runs alternated (before, after, after, before, ... : drift of the
# machine's load hits both alike), and the Markdown table printed with
# each cell's median over the rounds, the rounds' spread below it, and the
# machine's load (uptime) before, between and after the runs.
#
#   sh tests/bench/bench_table.sh [--before BUILD] [--after BUILD] [--rounds N]
#                                 [--out DIR] [--smoke] [--libigl DIR]
#
# BUILD is a build folder of this project (its bin/biotgrid and
# tests/bench/bench_rotfit, bench_solve are used); --after defaults to
# ./build, --before to nothing (then the table has one column). A before
# build of a commit without the quasi-newton method leaves that method's
# cells empty. The scenes are this checkout's (configs/scenes,
# tests/bench/scenes). Run it with the machine otherwise idle if you can;
# Every run has one core: OPENBLAS_NUM_THREADS=1, OMP_NUM_THREADS=1 and
# OMP_THREAD_LIMIT=1. The last is the one that counts for CHOLMOD: its
# supernodal factorization opens OpenMP teams of a fixed four threads
# (a num_threads clause, which OMP_NUM_THREADS does not cap) whose waiting
# cost 30-65 % more CPU time (user + system) in two Newton solves of bunny-edit
# on this 2-core machine.
#
# What each row measures:
#   slab, bunny    biotgrid solve --compare (every static method) to
#                  relative gradient 1e-6 on tests/bench/scenes/bending-slab.json
#                  (28,800 tets) and configs/scenes/bunny-edit.json: the wall
#                  time at which each method first reaches 1e-4 and 1e-6
#                  (report.json's trace, set-up included)
#   newton/cholmod bench_solve's Newton iteration on bunny-edit over CHOLMOD's
#                  factorization + solve alone on the same matrix, in wall time and
#                  (bench_solve from this branch on) in the thread's CPU time,
#                  which another process's load does not inflate; and in CPU
#                  time against the factorization and solve of the matrix stored
#                  in its factor's order (bg_sparse_reorder), as Newton stores it
#   bar-twist      bench_solve: Newton to 1e-8 over local/global to 1e-4
#   rotation fit   bench_rotfit: warm F + R + P, 552,960-tet box (M tets/s)
#   local/global   ms per iteration (trace, set-up excluded): bunny-edit
#                  from the slab/bunny run, tests/bench/scenes/box-196608.json
#                  from a 20-iteration run
#   libigl         (--libigl DIR: a libigl source tree, e.g. a clone of
#                  github.com/libigl/libigl; needs g++ and libeigen3-dev)
#                  local/global on the ARAP energy (the same scenes with
#                  λ = 0, no reference: libigl's energy) against libigl's
#                  arap_solve on the same mesh and handles, one thread, ms per
#                  iteration: bunny-edit 200 iterations here and 100 there,
#                  the box 60 here and 10 there (libigl's after one untimed
#                  iteration; its cost does not change from one to the next,
#                  while here the first ~20 cost ~7 % more: the warm-started
#                  rotation fits take more steps while the shape still
#                  moves). tests/bench/libigl/arap_bench.cpp is compiled out
#                  of the build (libigl is not a dependency) with -O3
#                  -DNDEBUG, as a user's release build would be.
# --smoke: one round, tiny sizes (bench_* --smoke, bar-twist for the
# scenes): checks that every figure is produced and parsed, not speed.
# Exit status: 0, or 1 when a run failed or a figure is missing.
set -u
here=$(cd "$(dirname "$0")" && pwd)
src=$(cd "$here/../.." && pwd)
before="" after="$src/build" rounds=2 out="" smoke=0 libigl=""
while [ $# -gt 0 ]; do
    case $1 in
        --before) before=$2; shift 2 ;;
        --after) after=$2; shift 2 ;;
        --rounds) rounds=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        --smoke) smoke=1; rounds=1; shift ;;
        --libigl) libigl=$2; shift 2 ;;
        *) echo "usage: bench_table.sh [--before BUILD] [--after BUILD] [--rounds N] [--out DIR] [--smoke] [--libigl DIR]" >&2
           exit 2 ;;
    esac
done
[ -n "$out" ] || out=$(mktemp -d "${TMPDIR:-/tmp}/bench-table.XXXXXX")
mkdir -p "$out" || exit 1
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 OMP_THREAD_LIMIT=1
command -v jq >/dev/null || { echo "bench_table.sh: needs jq" >&2; exit 1; }
# The command: bin/biotgrid in this tree, broker/biotgrid in builds of
# commits before it moved.
cmd() { if [ -x "$1/bin/biotgrid" ]; then echo "$1/bin/biotgrid"; else echo "$1/broker/biotgrid"; fi; }
for b in $before $after; do
    [ -x "$(cmd "$b")" ] || { echo "bench_table.sh: $b/bin/biotgrid missing (build it first)" >&2; exit 1; }
    for f in tests/bench/bench_rotfit tests/bench/bench_solve; do
        [ -x "$b/$f" ] || { echo "bench_table.sh: $b/$f missing (build it first)" >&2; exit 1; }
    done
done

if [ -n "$libigl" ]; then
    [ -f "$libigl/include/igl/arap.h" ] || { echo "bench_table.sh: $libigl/include/igl/arap.h missing (--libigl names a libigl source tree)" >&2; exit 1; }
    echo "bench_table.sh: compiling tests/bench/libigl/arap_bench.cpp against $libigl (about a minute)" >&2
    g++ -std=c++17 -O3 -DNDEBUG -I"$libigl/include" -I/usr/include/eigen3 \
        "$here/libigl/arap_bench.cpp" -o "$out/arap_bench" -lpthread || exit 1
fi

slab=$src/tests/bench/scenes/bending-slab.json
bunny=$src/configs/scenes/bunny-edit.json
box=$src/tests/bench/scenes/box-196608.json
tol=1e-6 boxits=20 sflag=""
if [ $smoke -eq 1 ]; then
    slab=$src/configs/scenes/bar-twist.json bunny=$src/configs/scenes/plate-bend.json
    box=$src/configs/scenes/bar-twist.json boxits=5 sflag=--smoke
fi
failed=0
loads=""
note_load() { loads="$loads
- $1: $(uptime | sed 's/^ *//')"; }

# The scene $1 as build $2 reads it: a build without the quasi-newton
# method refuses its per-method cap, so it gets a copy without it (in $3;
# meshes named by bare file names are found in the build's own folder).
scene_for() {
    if "$(cmd "$2")" solve --help | grep -q quasi-newton; then
        echo "$1"
    else
        jq 'if (.solver.max_iterations | type) == "object"
            then del(.solver.max_iterations["quasi-newton"]) else . end' "$1" \
            > "$3/$(basename "$1")" && echo "$3/$(basename "$1")"
    fi
}

# One pass of every measurement on build $1 into folder $2.
measure() {
    b=$1 d=$2
    mkdir -p "$d"
    methods=newton,local-global
    "$(cmd "$b")" solve --help | grep -q quasi-newton && methods=$methods,quasi-newton
    "$b/tests/bench/bench_rotfit" $sflag > "$d/rotfit.txt" 2>&1 || failed=1
    "$b/tests/bench/bench_solve" $sflag > "$d/solve.txt" 2>&1 || failed=1
    for s in slab bunny; do
        eval scene=\$$s
        "$(cmd "$b")" solve "$(scene_for "$scene" "$b" "$d")" --compare $methods \
            --tolerance $tol --quiet --out "$d/$s" > "$d/$s.txt" 2>&1
        [ $? -le 1 ] || failed=1
    done
    "$(cmd "$b")" solve "$(scene_for "$box" "$b" "$d")" --method local-global \
        --tolerance 1e-12 --max-iterations $boxits --quiet --out "$d/box" > "$d/box.txt" 2>&1
    [ $? -le 1 ] || failed=1
    [ -n "$libigl" ] || return 0
    for s in bunny box; do
        eval scene=\$$s
        its=200 # the box: 60, past its first iterations' slower warm-started fits
        [ $s = box ] && its=$((boxits * 3))
        jq '.material.lambda = 0 | del(.reference)' "$(scene_for "$scene" "$b" "$d")" \
            > "$d/$s-arap.json" || failed=1
        "$(cmd "$b")" solve "$d/$s-arap.json" --method local-global --tolerance 1e-14 \
            --max-iterations $its --quiet --out "$d/$s-arap" > "$d/$s-arap.txt" 2>&1
        [ $? -le 1 ] || failed=1
    done
}

# libigl's arap_solve on scene $1's mesh and handles (box_fraction handles
# moved by a translation: the scenes this table uses), $2 iterations.
measure_libigl() {
    mesh=$(jq -r 'if (.mesh | type) == "object" and .mesh.generate == "box"
        then "box:\(.mesh.cells | map(tostring) | join(",")):\((.mesh.size // [1, 1, 1]) | map(tostring) | join(","))"
        else .mesh end' "$1")
    case $mesh in
        box:*) ;;
        *) mesh=$(dirname "$(cmd "$after")")/../share/biotgrid/meshes/$mesh ;;
    esac
    handles=$(jq -r '.handles[] | [.select.box_fraction.min, .select.box_fraction.max,
        (.transform.translate // [0, 0, 0])] | flatten | map(tostring) | join(",")' "$1")
    IGL_NUM_THREADS=1 "$out/arap_bench" "$mesh" "$2" $handles
}

# Round r: before then after on odd rounds, after then before on even ones.
note_load "start"
r=1
while [ $r -le "$rounds" ]; do
    if [ $((r % 2)) -eq 1 ]; then order="before after"; else order="after before"; fi
    for side in $order; do
        eval b=\$$side
        [ -n "$b" ] || continue
        measure "$b" "$out/$side-$r"
        note_load "after round $r, $side"
    done
    if [ -n "$libigl" ]; then
        mkdir -p "$out/libigl-$r"
        measure_libigl "$bunny" 100 > "$out/libigl-$r/bunny.txt" 2>&1 || failed=1
        measure_libigl "$box" 10 > "$out/libigl-$r/box.txt" 2>&1 || failed=1
        note_load "after round $r, libigl"
    fi
    r=$((r + 1))
done

# --- figures of one run folder ---------------------------------------------
figure() { sed -n "s/^figure $2=\([^ ]*\) .*/\1/p" "$1" | head -1; }
# seconds at which method $3 of report $1 first reaches relative gradient $2
reach() {
    jq -r --arg m "$3" --argjson t "$2" \
        '[.runs[] | select(.method == $m) | .trace[] | select(.relative_gradient <= $t)
          | .seconds][0] // empty' "$1" 2>/dev/null
}
# ms per iteration of method $2 in report $1 (trace: set-up excluded)
per_it() {
    jq -r --arg m "$2" '[.runs[] | select(.method == $m)][0] // empty
        | if .iterations > 0 then (.trace[-1].seconds - .trace[0].seconds) / .iterations * 1000
          else empty end' "$1" 2>/dev/null
}
value() { # key side round
    d=$out/$2-$3
    case $1 in
        rotfit) v=$(figure "$d/rotfit.txt" rotfit.3d.smooth.warm.throughput)
                [ -n "$v" ] && v=$(awk -v x="$v" 'BEGIN { printf "%.1f", x / 1e6 }') ;;
        ratio) v=$(figure "$d/solve.txt" solve.bunny-edit.newton_over_cholmod)
               [ $smoke -eq 1 ] && v=$(figure "$d/solve.txt" solve.box-864.newton_over_cholmod) ;;
        ratio_cpu) v=$(figure "$d/solve.txt" solve.bunny-edit.newton_over_cholmod_cpu) ;;
        ratio_stored) v=$(figure "$d/solve.txt" solve.bunny-edit.newton_over_cholmod_stored_cpu) ;;
        bartwist) v=$(figure "$d/solve.txt" accuracy.bar-twist.newton_over_local_global) ;;
        lg_bunny) v=$(per_it "$d/bunny/report.json" local-global) ;;
        lg_box) v=$(per_it "$d/box/report.json" local-global) ;;
        arap_bunny | arap_box)
            v=$(per_it "$d/${1#arap_}-arap/report.json" local-global) ;;
        igl_bunny | igl_box)
            v=$(figure "$out/libigl-$3/${1#igl_}.txt" libigl.ms_per_iteration) ;;
        over_bunny | over_box) # this build's ARAP iteration over libigl's, same round
            a=$(value "arap_${1#over_}" "$2" "$3") l=$(value "igl_${1#over_}" "$2" "$3")
            v=""
            [ -n "$a" ] && [ -n "$l" ] && v=$(awk -v a="$a" -v l="$l" 'BEGIN { printf "%.4f", a / l }') ;;
        *) set -- $(echo "$1" | tr : ' ') "$2" "$3"
           v=$(reach "$d/$1/report.json" "$3" "$2") ;;
    esac
    echo "$v"
}
# median of the numbers on stdin ("" when none)
median() { sort -g | awk '{ v[NR] = $1 } END { if (NR == 0) exit;
    if (NR % 2) print v[(NR + 1) / 2]; else print (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }
cell() { # key side [format]
    [ -n "$(eval echo \$$2)" ] || { echo "-"; return; }
    vals="" r=1
    while [ $r -le "$rounds" ]; do
        v=$(value "$1" "$2" $r)
        [ -n "$v" ] && vals="$vals $v"
        r=$((r + 1))
    done
    m=$(for v in $vals; do echo "$v"; done | median)
    [ -n "$m" ] || { echo "-"; return; }
    printf "${3:-%.3g}" "$m"
}
raw() { # key side: every round's value
    [ -n "$(eval echo \$$2)" ] || { echo "-"; return; }
    r=1 vals=""
    while [ $r -le "$rounds" ]; do
        v=$(value "$1" "$2" $r)
        vals="$vals${vals:+, }${v:--}"
        r=$((r + 1))
    done
    echo "$vals"
}
reached() { # scene side: "newton a / b s, local-global c / d s, quasi-newton e / f s"
    line=""
    for m in newton local-global quasi-newton; do
        a=$(cell "$1:$m:1e-4" "$2" "%.2f") z=$(cell "$1:$m:$tol" "$2" "%.2f")
        [ "$a" = "-" ] && [ "$z" = "-" ] && continue
        line="$line${line:+, }$m $a / $z s"
    done
    echo "${line:--}"
}

echo
echo "| measure | before | after | target |"
echo "|---|---|---|---|"
echo "| time to relative gradient 1e-4 / $tol, $(basename "$slab" .json) | $(reached slab before) | $(reached slab after) | a method <= half the best at 1e-4 and <= the best at $tol |"
echo "| same, $(basename "$bunny" .json) | $(reached bunny before) | $(reached bunny after) | same |"
echo "| Newton iteration / CHOLMOD factor + solve alone (bench_solve), bunny | $(cell ratio before "%.2fx") | $(cell ratio after "%.2fx") | <= 1.1x |"
echo "| the same in this thread's CPU time, iterations 2-5 (a bench_solve of this branch on) | $(cell ratio_cpu before "%.2fx") | $(cell ratio_cpu after "%.2fx") | <= 1.1x |"
echo "| the same, CPU time, against CHOLMOD on the matrix stored in its factor's order as Newton now stores it (what Newton adds to its own factor + solve) | $(cell ratio_stored before "%.2fx") | $(cell ratio_stored after "%.2fx") | |"
echo "| bar-twist, Newton to 1e-8 against local/global to 1e-4 | $(cell bartwist before "%.2fx") | $(cell bartwist after "%.2fx") | < 1 |"
echo "| rotation fit, bench_rotfit warm (M tets/s) | $(cell rotfit before "%.1f") | $(cell rotfit after "%.1f") | >= 35 |"
echo "| local/global iteration, $(basename "$bunny" .json) / $(basename "$box" .json) (ms) | $(cell lg_bunny before "%.2f") / $(cell lg_box before "%.1f") | $(cell lg_bunny after "%.2f") / $(cell lg_box after "%.1f") | about half of before |"
if [ -n "$libigl" ]; then
    echo "| local/global on the ARAP energy (λ = 0), ms per iteration, $(basename "$bunny" .json) / $(basename "$box" .json); libigl's arap_solve: $(cell igl_bunny after "%.2f") / $(cell igl_box after "%.1f") ms | $(cell arap_bunny before "%.2f") / $(cell arap_box before "%.1f") | $(cell arap_bunny after "%.2f") / $(cell arap_box after "%.1f") | |"
    echo "| the same over libigl's (each round's own ratio) | $(cell over_bunny before "%.3fx") / $(cell over_box before "%.3fx") | $(cell over_bunny after "%.3fx") / $(cell over_box after "%.3fx") | <= 0.1x on both |"
fi
echo
echo "Medians over $rounds round(s), runs alternated (odd rounds before then after, even rounds"
echo "after then before); one thread (OPENBLAS_NUM_THREADS, OMP_NUM_THREADS, OMP_THREAD_LIMIT = 1)."
echo "Every round's value:"
echo
keys="rotfit ratio ratio_cpu ratio_stored bartwist lg_bunny lg_box"
[ -n "$libigl" ] && keys="$keys igl_bunny igl_box arap_bunny arap_box over_bunny over_box"
for key in $keys; do
    echo "- $key: before [$(raw $key before)], after [$(raw $key after)]"
done
for s in slab bunny; do
    for m in newton local-global quasi-newton; do
        for t in 1e-4 $tol; do
            echo "- $s $m to $t (s): before [$(raw "$s:$m:$t" before)], after [$(raw "$s:$m:$t" after)]"
        done
    done
done
echo
echo "Load (uptime):$loads"
echo "Runs' outputs: $out"

# Every figure present on the after side (the smoke test's check).
missing=0
for key in rotfit ratio bartwist lg_bunny lg_box slab:newton:1e-4 slab:local-global:1e-4 \
           bunny:newton:1e-4; do
    [ -n "$(value $key after 1)" ] || { echo "bench_table.sh: no figure '$key' (after, round 1)" >&2
                                        missing=1; }
done
[ $failed -eq 0 ] && [ $missing -eq 0 ]
