#!/usr/bin/env bash
# A/B of two nf_tracer builds at equal time, back to back on one machine: this checkout's
# build/examples/nf_tracer with A_FLAGS against another build (a worktree of another commit,
# say) with B_FLAGS, each scene at 30 s on 2 threads for seeds 1 2 3, relMSE against the
# scenes' Tungsten references (the statue has none: a 150-s unguided reference is rendered
# once into the output directory). Prints one line per run and the mean ratio A / B per scene.
# About 10 minutes (18 runs of 30 s, plus the statue's reference once); the machine should be
# otherwise idle.
#
#   scripts/ab-tracers.sh B_TRACER ["B_FLAGS"] ["A_FLAGS"]
#
# Example (the defaults against the study's eight flags at 1b6522f, docs/equal-time.md):
#   git worktree add /tmp/old 1b6522f && (cd /tmp/old && cmake --preset release &&
#       cmake --build build -j2 --target nf_tracer)
#   scripts/ab-tracers.sh /tmp/old/build/examples/nf_tracer "--guide-prob 0.7 --mis-training
#       --guide-min-roughness 0.3 --clamp-quantile 0.99 --train-fraction 0.15 --sh-bands 0
#       --guide-max-boost 10 --light-mis-depth 2"
set -euo pipefail
cd "$(dirname "$0")/.."
B=${1:?usage: scripts/ab-tracers.sh B_TRACER [B_FLAGS] [A_FLAGS]}
B_FLAGS=${2:-}
A_FLAGS=${3:-}
A=build/examples/nf_tracer
OUT=${NF_AB_OUT:-out/ab}
SEEDS=${NF_AB_SEEDS:-1 2 3}
SCENES=${NF_AB_SCENES:-veach-ajar statue cornell-box}
BUDGET=${NF_AB_BUDGET:-30}
test -x "$A" && test -x "$B" || { echo "ab-tracers.sh: build both tracers first" >&2; exit 1; }
mkdir -p "$OUT"
declare -A SIZE=([cornell-box]="--width 256 --height 256" [veach-ajar]="--width 320 --height 180"
                 [veach-bidir]="--width 256 --height 256" [statue]="--width 256 --height 256"
                 [veach-ajar-fog]="--width 320 --height 180")
reference() {
    local s=$1 r=examples/scenes/$1/reference-tungsten.exr
    if [ -f "$r" ]; then echo "$r"; return; fi
    if [ ! -f "$OUT/$s-ref.exr" ]; then
        "$A" --scene "examples/scenes/$s/scene.xml" ${SIZE[$s]} --no-guiding --threads 2 \
            --seed 999 --time-budget 150 --out "$OUT/$s-ref" > "$OUT/$s-ref.log" 2>&1
    fi
    echo "$OUT/$s-ref.exr"
}
for s in $SCENES; do reference "$s" > /dev/null; done
for seed in $SEEDS; do
    for s in $SCENES; do
        for w in a b; do
            if [ "$w" = a ]; then bin=$A; flags=$A_FLAGS; else bin=$B; flags=$B_FLAGS; fi
            # shellcheck disable=SC2086 # flags are lists of options
            "$bin" --scene "examples/scenes/$s/scene.xml" ${SIZE[$s]} --threads 2 --seed "$seed" \
                --time-budget "$BUDGET" --reference "$(reference "$s")" --out "$OUT/$s-$w-$seed" \
                $flags > "$OUT/$s-$w-$seed.log" 2>&1
            # The error line's relMSE, not the tail line's (relMSE without the worst pixels).
            err=$(grep -E '^error' "$OUT/$s-$w-$seed.log" | grep -Eo 'relMSE [0-9.e+-]+' | tail -n 1)
            echo "$s $w $seed $err"
        done
    done
done | tee "$OUT/runs.txt"
awk '{ v[$1" "$2] += $5; n[$1" "$2]++ }
     END { for (k in v) { split(k, p, " "); if (p[2] == "a") {
               a = v[k] / n[k]; b = v[p[1]" b"] / n[p[1]" b"];
               printf "%s: A %.6g, B %.6g, A / B %.2f\n", p[1], a, b, a / b } } }' "$OUT/runs.txt"
