#!/usr/bin/env bash
# The choice between guided and plain render passes at equal time (docs/equal-time.md, "Guided
# or plain passes"): each scene at 30 s on 2 threads with the tracer's defaults, with every
# render pass guided (--variant guided-passes: the defaults before the choice) and with plain
# path tracing (--no-guiding), one seed after another, relMSE and MAPE against references.
# References: veach-ajar's and veach-bidir's Tungsten renders; the Cornell box and the statue
# get unguided ones of our own, 4096 paths per pixel, rendered once into the output directory
# (about 5 minutes). Prints one line per run and a summary per scene and method (mean and
# standard deviation over the seeds, and relMSE without each run's 10 worst pixels, which
# single rare paths can decide: docs/tracer-measurements.md, "Error metrics"). About 25 minutes (45 runs of 30 s); the machine should be
# otherwise idle. Runs are cached in the output directory (a complete log is not run again).
#
#   scripts/pass-choice-study.sh            the study
#   scripts/pass-choice-study.sh --smoke    one scene, 3-s budgets, one seed, a 64-spp
#                                           reference: about a minute
#
# Environment: NF_PC_OUT (default out/pass-choice), NF_PC_BUDGET (30), NF_PC_SEEDS (1 2 3),
# NF_PC_BIDIR_SEEDS (1 2 3 4 5), NF_PC_SCENES (veach-ajar statue cornell-box veach-bidir),
# NF_PC_FLAGS (options for every run, "--model large" say) and NF_PC_TAG (a name for them, in
# the runs' file names and lines).
set -euo pipefail
cd "$(dirname "$0")/.."
TRACER=build/examples/nf_tracer
PAPER=build/examples/nf_paper
OUT=${NF_PC_OUT:-out/pass-choice}
BUDGET=${NF_PC_BUDGET:-30}
SEEDS=${NF_PC_SEEDS:-1 2 3}
BIDIR_SEEDS=${NF_PC_BIDIR_SEEDS:-1 2 3 4 5}
SCENES=${NF_PC_SCENES:-veach-ajar statue cornell-box veach-bidir}
REF_SPP=4096
FLAGS=${NF_PC_FLAGS:-}
TAG=${NF_PC_TAG:-}
if [ "${1:-}" = --smoke ]; then
    OUT=out/pass-choice-smoke BUDGET=3 SEEDS=1 BIDIR_SEEDS=1 SCENES=cornell-box REF_SPP=64
fi
test -x "$TRACER" || { echo "pass-choice-study.sh: build $TRACER first" >&2; exit 1; }
mkdir -p "$OUT"
declare -A SIZE=([cornell-box]="--width 256 --height 256" [veach-ajar]="--width 320 --height 180"
                 [veach-bidir]="--width 256 --height 256" [statue]="--width 256 --height 256")
declare -A METHOD=([defaults]="" [guided-passes]="--variant guided-passes" [plain]="--no-guiding")
reference() {
    local s=$1
    case $s in
    veach-ajar | veach-bidir) echo "examples/scenes/$s/reference-tungsten.exr" ;;
    *)
        if [ ! -f "$OUT/$s-ref.exr" ]; then
            # shellcheck disable=SC2086 # SIZE holds options
            "$PAPER" --scene "examples/scenes/$s/scene.xml" ${SIZE[$s]} --reference-mode \
                --spp "$REF_SPP" --threads 2 --seed 999 --out "$OUT/$s-ref" > "$OUT/$s-ref.log" 2>&1
        fi
        echo "$OUT/$s-ref.exr" ;;
    esac
}
for s in $SCENES; do reference "$s" > /dev/null; done
for s in $SCENES; do
    seeds=$SEEDS
    [ "$s" = veach-bidir ] && seeds=$BIDIR_SEEDS
    for seed in $seeds; do
        for m in defaults guided-passes plain; do
            log=$OUT/$s$TAG-$m-$seed.log
            # A run whose log is complete is not run again: delete it to rerun.
            grep -q '^error' "$log" 2>/dev/null ||
            # shellcheck disable=SC2086 # SIZE and METHOD hold options
            "$TRACER" --scene "examples/scenes/$s/scene.xml" ${SIZE[$s]} --threads 2 \
                --seed "$seed" --time-budget "$BUDGET" --reference "$(reference "$s")" \
                --out "$OUT/$s$TAG-$m-$seed" ${METHOD[$m]} $FLAGS 2>&1 | tr '\r' '\n' | grep -v '^\s*$' > "$log"
            err=$(grep -Eo 'MAPE [0-9.e+-]+, relMSE [0-9.e+-]+' "$log" | tail -n 1 | tr -d ,)
            # relMSE without the run's 10 worst pixels (the tail line; 0 in a log without it).
            body=$(awk '/^tail/ { print $NF }' "$log" | tail -n 1)
            cpu=$(awk '/^(guided|plain) .*render passes/ { print $1, $2 }' "$log" | tr '\n' ' ')
            echo "$s$TAG $m $seed $err body ${body:-0} passes: $cpu"
        done
    done
done | tee "$OUT/runs$TAG.txt"
# scene method seed MAPE m relMSE r body b ...: mean and standard deviation per scene and
# method, and the mean relMSE without each run's 10 worst pixels.
awk '{ k = $1 " " $2; n[k]++; r[k] += $7; r2[k] += $7 * $7; m[k] += $5; m2[k] += $5 * $5
       b[k] += $9 }
     END { for (k in n) {
               mr = r[k] / n[k]; mm = m[k] / n[k]
               sr = n[k] > 1 ? sqrt((r2[k] - n[k] * mr * mr) / (n[k] - 1)) : 0
               sm = n[k] > 1 ? sqrt((m2[k] - n[k] * mm * mm) / (n[k] - 1)) : 0
               printf "%s: relMSE %.4g +- %.2g, MAPE %.4g +- %.2g, ", k, mr, sr, mm, sm
               printf "relMSE without the 10 worst pixels %.4g (%d seeds)\n", b[k] / n[k], n[k] } }' \
    "$OUT/runs$TAG.txt" | sort | tee "$OUT/summary$TAG.txt"
