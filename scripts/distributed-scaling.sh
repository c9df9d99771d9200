#!/usr/bin/env bash
# How nf_paper's training scales over MPI ranks on this machine (docs/distributed.md): the
# same job (veach-ajar 320 x 180, batches of 4,096 paths, the small model) as one process with
# one thread, as 2 ranks x 1 thread under mpirun, and as one process with 2 threads, ROUNDS
# times in turn. It prints a Markdown table of milliseconds per training iteration (rank 0's
# wall time, tracing and the optimizer step with its reductions) and the speed-ups, and checks
# that every run saved the same model. About 1.5 minutes with the defaults (100 iterations, 3
# rounds); run it on an idle machine.
#
#   scripts/distributed-scaling.sh [ITERATIONS [ROUNDS]]     (defaults 100 and 3)
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
ITERATIONS=${1:-100}
ROUNDS=${2:-3}
TRACER=build/examples/nf_paper
OUT=out/distributed-scaling
test -x "$TRACER" || { echo "build first: cmake -S . -B build && cmake --build build -j2" >&2; exit 1; }
command -v mpirun > /dev/null || { echo "mpirun is missing: scripts/install-deps.sh" >&2; exit 1; }
mkdir -p "$OUT"
[ "$(id -u)" -eq 0 ] && export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1

JOB=(--scene examples/scenes/veach-ajar/scene.xml --width 320 --height 180 --lr 1e-3
     --iterations "$ITERATIONS" --batch 4096 --eval-every 0 --spp 1)

# run NAME THREADS [LAUNCHER...]: the job; prints its milliseconds per training iteration
run() {
    local name=$1 threads=$2
    shift 2
    "$@" "$TRACER" "${JOB[@]}" --threads "$threads" --out "$OUT/$name" \
        --save-model "$OUT/$name.nf" > "$OUT/$name.log"
    sed -nE 's/^trained .*: ([0-9.]+) ms per iteration.*/\1/p' "$OUT/$name.log"
}

echo "| round | 1 process x 1 thread | 2 ranks x 1 thread | 1 process x 2 threads | 2 ranks / 1 | 2 threads / 1 |"
echo "|---|---|---|---|---|---|"
for ((r = 1; r <= ROUNDS; ++r)); do
    one=$(run "one-$r" 1)
    ranks=$(run "ranks-$r" 1 mpirun -n 2 --bind-to none)
    threads=$(run "threads-$r" 2)
    for name in "ranks-$r" "threads-$r"; do
        cmp -s "$OUT/one-1.nf" "$OUT/$name.nf" || { echo "$name saved another model" >&2; exit 1; }
    done
    awk -v r="$r" -v a="$one" -v b="$ranks" -v c="$threads" 'BEGIN {
        printf "| %d | %.1f ms | %.1f ms | %.1f ms | %.2fx | %.2fx |\n", r, a, b, c, a / b, a / c }'
done
echo
echo "ms per training iteration: rank 0's wall time per iteration (tracing 4,096 paths and the"
echo "optimizer step with its reductions); $ITERATIONS iterations per run; every run saved the same model."
echo "$(lscpu | sed -nE 's/^Model name: +//p'), $(nproc) cores; $(mpirun --version | head -n 1);" \
    "commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
