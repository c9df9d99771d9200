#!/usr/bin/env bash
# A/B of two nf_tracer builds at equal time, back to back on one machine: this checkout's
# build/examples/nf_tracer with A_FLAGS against another build (a worktree of another commit,
# say) with B_FLAGS, each scene at 30 s on 2 threads for seeds 1 2 3, relMSE and MAPE against
# the scenes' Tungsten references (a scene without one, the statue, gets a 150-s unguided
# reference rendered once into the output directory). Prints one line per run and the ratios
# A / B of the means per scene and budget. About 10 minutes (18 runs of 30 s, plus the
# statue's reference once); the machine should be otherwise idle.
#
#   scripts/ab-tracers.sh B_TRACER ["B_FLAGS"] ["A_FLAGS"]
#
# NF_AB_SCENES, NF_AB_SEEDS and NF_AB_BUDGETS (a list of seconds) choose the runs;
# NF_AB_REFERENCES=own renders every scene's reference (NF_AB_REFERENCE_SECONDS, default 150),
# Tungsten's or not. Guided against plain path tracing, 5 seeds at 10, 20 and 30 s (about 32
# minutes for two scenes, their 240-s references included):
#   NF_AB_SCENES="cornell-box veach-bidir" NF_AB_SEEDS="1 2 3 4 5" NF_AB_BUDGETS="10 20 30" \
#       NF_AB_REFERENCES=own NF_AB_REFERENCE_SECONDS=240 \
#       scripts/ab-tracers.sh build/examples/nf_tracer --no-guiding
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
A=${NF_AB_A:-build/examples/nf_tracer}  # NF_AB_A: another A build
OUT=${NF_AB_OUT:-out/ab}
SEEDS=${NF_AB_SEEDS:-1 2 3}
SCENES=${NF_AB_SCENES:-veach-ajar statue cornell-box}
BUDGETS=${NF_AB_BUDGETS:-${NF_AB_BUDGET:-30}}
REFERENCES=${NF_AB_REFERENCES:-tungsten}
REFERENCE_SECONDS=${NF_AB_REFERENCE_SECONDS:-150}
test -x "$A" && test -x "$B" || { echo "ab-tracers.sh: build both tracers first" >&2; exit 1; }
mkdir -p "$OUT"
declare -A SIZE=([cornell-box]="--width 256 --height 256" [veach-ajar]="--width 320 --height 180"
                 [veach-bidir]="--width 256 --height 256" [statue]="--width 256 --height 256"
                 [veach-ajar-fog]="--width 320 --height 180")
reference() {
    local s=$1 r=examples/scenes/$1/reference-tungsten.exr
    if [ "$REFERENCES" != own ] && [ -f "$r" ]; then echo "$r"; return; fi
    if [ ! -f "$OUT/$s-ref.exr" ]; then
        "$A" --scene "examples/scenes/$s/scene.xml" ${SIZE[$s]} --no-guiding --threads 2 \
            --seed 999 --time-budget "$REFERENCE_SECONDS" --out "$OUT/$s-ref" > "$OUT/$s-ref.log" 2>&1
    fi
    echo "$OUT/$s-ref.exr"
}
for s in $SCENES; do reference "$s" > /dev/null; done
for budget in $BUDGETS; do
    for seed in $SEEDS; do
        for s in $SCENES; do
            for w in a b; do
                if [ "$w" = a ]; then bin=$A; flags=$A_FLAGS; else bin=$B; flags=$B_FLAGS; fi
                log=$OUT/$s-$budget-$w-$seed.log
                # shellcheck disable=SC2086 # flags are lists of options
                "$bin" --scene "examples/scenes/$s/scene.xml" ${SIZE[$s]} --threads 2 \
                    --seed "$seed" --time-budget "$budget" --reference "$(reference "$s")" \
                    --out "$OUT/$s-$budget-$w-$seed" $flags > "$log" 2>&1
                # The error line's figures, not the tail line's (relMSE without the worst
                # pixels).
                line=$(grep -E '^error' "$log" | tail -n 1)
                rel=$(echo "$line" | grep -Eo 'relMSE [0-9.e+-]+')
                mape=$(echo "$line" | grep -Eo 'MAPE [0-9.e+-]+')
                echo "$s $budget $w $seed $rel $mape"
            done
        done
    done
done | tee "$OUT/runs.txt"
# columns: scene budget a|b seed relMSE value MAPE value
awk '{ k = $1" "$2; r[k" "$3] += $6; m[k" "$3] += $8; n[k" "$3]++; keys[k] = 1 }
     END { for (k in keys) {
               ra = r[k" a"] / n[k" a"]; rb = r[k" b"] / n[k" b"];
               ma = m[k" a"] / n[k" a"]; mb = m[k" b"] / n[k" b"];
               printf "%s s: relMSE A %.6g, B %.6g, A / B %.3f; MAPE A %.6g, B %.6g, A / B %.3f\n",
                      k, ra, rb, ra / rb, ma, mb, ma / mb } }' "$OUT/runs.txt" | sort
