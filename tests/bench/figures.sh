#!/bin/sh
# figures.sh [--build BUILD] [--rounds N] [--out DIR] [--smoke]
# Every benchmark figure the top-level README quotes, regenerated in one
# run and printed as Markdown with the machine and its load (uptime)
# before and after each part, so the README's figures are a copy of this
# output, never typed in:
#
#   solver    tests/bench/bench_table.sh: time to accuracy per method, Newton
#             against CHOLMOD alone, the rotation fit, the local/global iteration
#   grid      tests/broker/bench_grid.sh: bunny-edit and a generated
#             28,800-tet slab through the local grid (submit -> result files)
#             against solve in process, alternated rounds
#   curve     tests/broker/bench_curve.sh: the same job with CURVE and without
#   checkpoint tests/broker/bench_checkpoint.sh: the same job on a grid that
#             keeps checkpoints to recover lost agents and on one that does not
#   rest      bench_rest: durable submits through REST, 64 clients
#   market    tests/market_live/live.sh bench: allocation latency per
#             mechanism on 8 agents, and jobs per second at saturation
#
# BUILD defaults to ./build; N rounds (default 2) for the alternated parts.
# --smoke: small scenes, one round, short runs: checks every part runs and
# its figures are found (the suite's bench.figures.smoke), not speed.
# Takes 25-40 minutes in full on a 2-core machine. Exit 0, or 1 when a part
# failed or printed no figure.
set -u
here=$(cd "$(dirname "$0")" && pwd)
src=$(cd "$here/../.." && pwd)
build=$src/build rounds=2 out="" smoke=0
while [ $# -gt 0 ]; do
    case $1 in
        --build) build=$2; shift 2 ;;
        --rounds) rounds=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        --smoke) smoke=1; rounds=1; shift ;;
        *) echo "usage: figures.sh [--build BUILD] [--rounds N] [--out DIR] [--smoke]" >&2; exit 2 ;;
    esac
done
[ -n "$out" ] || out=$(mktemp -d "${TMPDIR:-/tmp}/figures.XXXXXX")
mkdir -p "$out" || exit 1
bin=$build/bin/biotgrid
[ -x "$bin" ] || { echo "figures.sh: $bin missing (build it first)" >&2; exit 1; }
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 OMP_THREAD_LIMIT=1
failed=0

bunny=$src/configs/scenes/bunny-edit.json slab=$src/tests/bench/scenes/bending-slab.json
restargs="--clients 64 --jobs 8000" mrounds=30 mjobs=200
mesh=$build/share/biotgrid/meshes/bunny.mesh  # bench_curve.sh uploads it beside the scene
if [ $smoke -eq 1 ]; then
    bunny=$src/configs/scenes/bar-twist.json slab=$src/configs/scenes/plate-bend.json mesh=""
    restargs=--smoke mrounds=3 mjobs=20
fi

# part NAME COMMAND...: runs it into $out/NAME.txt, notes the load around it.
part() {
    name=$1; shift
    echo "- $name: $(uptime | sed 's/^ *//')" >>"$out/loads.txt"
    "$@" >"$out/$name.txt" 2>&1 || { echo "figures.sh: $name failed (see $out/$name.txt)" >&2; failed=1; }
}
# cell FILE PATTERN: the lines of FILE matching PATTERN, trimmed, joined by "; ".
cell() {
    c=$(grep -E "$2" "$1" 2>/dev/null | sed 's/^ *//; s/  */ /g' | paste -sd ';' - | sed 's/;/; /g')
    [ -n "$c" ] || { echo "figures.sh: no figure matching '$2' in $1" >&2; failed=1; c="(missing)"; }
    printf '%s' "$c"
}

started=$(uptime | sed 's/^ *//')
tflag=""; [ $smoke -eq 1 ] && tflag=--smoke
part solver sh "$here/bench_table.sh" --after "$build" --rounds "$rounds" $tflag --out "$out/solver"
part grid-bunny sh "$src/tests/broker/bench_grid.sh" "$bin" "$bunny" "$out/grid-bunny" posted "$rounds"
part grid-slab sh "$src/tests/broker/bench_grid.sh" "$bin" "$slab" "$out/grid-slab" posted "$rounds"
part curve sh "$src/tests/broker/bench_curve.sh" "$bin" "$bunny" "$mesh" "$out/curve" "$rounds"
part checkpoint sh "$src/tests/broker/bench_checkpoint.sh" "$bin" "$bunny" "$out/checkpoint" "$((rounds + 1))"
part rest "$build/tests/broker/bench_rest" $restargs --dir "$out"
part market sh "$src/tests/market_live/live.sh" "$bin" "$build/tests/market_live/bench_alloc" \
    "$out/market" bench "$mrounds" "$mjobs" 16
finished=$(uptime | sed 's/^ *//')

echo "# biotgrid benchmark figures"
echo
echo "$(getconf _NPROCESSORS_ONLN) cores ($(grep -m1 'model name' /proc/cpuinfo | sed 's/.*: //')), one BLAS and OpenMP thread per process."
echo "Load (uptime) at the start: $started; at the end: $finished; before each part:"
echo
cat "$out/loads.txt"
echo
echo "## The solver"
echo
sed -n '/^|/p' "$out/solver.txt"
echo
echo "## The grid, REST and the live market"
echo
echo "| what | command | figures |"
echo "|---|---|---|"
echo "| $(basename "$bunny" .json) through the local grid (posted), submit -> result files, against solve | \`bench_grid.sh\` | $(cell "$out/grid-bunny.txt" '^round|median') |"
echo "| $(basename "$slab" .json) the same | \`bench_grid.sh\` | $(cell "$out/grid-slab.txt" '^round|median') |"
echo "| the same job with CURVE against plaintext | \`bench_curve.sh\` | $(cell "$out/curve.txt" 'mean|CURVE /') |"
echo "| the same job keeping checkpoints (recovery on) against not | \`bench_checkpoint.sh\` | $(cell "$out/checkpoint.txt" 'median ratio') |"
echo "| durable submits through REST | \`bench_rest $restargs\` | $(cell "$out/rest.txt" 'REST, |group commit /') |"
echo "| allocation latency and saturation, 8 agents | \`live.sh bench $mrounds $mjobs\` | $(cell "$out/market.txt" 'median|jobs/s') |"
echo
echo "Raw outputs: $out"
exit $failed
