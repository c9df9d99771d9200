#!/usr/bin/env bash
# Reproduces the study of "On Cosine Prior Distributions for Neural Path Guiding" with the
# example tracer and regenerates every table and plot of docs/results.md:
#   docs/results/tables.md   all tables (means, standard deviations and ranges over seeds)
#   docs/results/*.png       convergence, equal-time and crop plots (gnuplot)
#
# Usage (from the repository root, after ./scripts/install-deps.sh --study):
#   ./scripts/paper-study.sh
#
# Every configuration runs with seeds 1, 2 and 3; each run is one single-threaded
# nf_paper process and NF_STUDY_JOBS of them (default: the number of processors) run at
# once, so that all timings are for one thread. Runs land in out/study/runs/; a run whose
# log is complete is not run again, so an interrupted study resumes where it stopped
# (delete out/study to start over). NF_STUDY_ONLY_AGGREGATE=1 skips the runs and only
# rebuilds the tables and plots from out/study/runs/.
#
# Not part of the test suite or CI: it takes about 45 minutes on a 2-core machine (see
# docs/results.md for the measured time).
set -euo pipefail

cd "$(dirname "$0")/.."
STUDY=out/study
RUNS=$STUDY/runs
JOBS=${NF_STUDY_JOBS:-$(nproc)}
TRACER=build/examples/nf_paper
SEEDS="1 2 3"

for tool in gnuplot python3 cmake; do
    command -v "$tool" >/dev/null || {
        echo "paper-study.sh: '$tool' is missing; run ./scripts/install-deps.sh --study" >&2
        exit 1
    }
done

start=$(date +%s)
mkdir -p "$RUNS"

if [ "${NF_STUDY_ONLY_AGGREGATE:-0}" != 1 ]; then
    cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
    cmake --build build -j"$JOBS" --target nf_paper >/dev/null
    [ -x "$TRACER" ] || { echo "paper-study.sh: $TRACER was not built" >&2; exit 1; }

    # Scenes, at 256 pixels wide: an integer fraction of the Tungsten references (1024 x 1024
    # and 1280 x 720), which the tracer box-downsamples. Learning rates are the paper's.
    declare -A SCENE=([cornell-box]=examples/scenes/cornell-box/scene.xml
                      [veach-ajar]=examples/scenes/veach-ajar/scene.xml
                      [statue]=examples/scenes/statue/scene.xml)
    declare -A SIZE=([cornell-box]="--width 256 --height 256"
                     [veach-ajar]="--width 256 --height 144"
                     [statue]="--width 256 --height 256")
    declare -A REF=([cornell-box]=examples/scenes/cornell-box/reference-tungsten.exr
                    [veach-ajar]=examples/scenes/veach-ajar/reference-tungsten.exr
                    [statue]=$STUDY/statue-reference.exr)
    declare -A LR=([cornell-box]=5e-3 [veach-ajar]=1e-3 [statue]=1e-3)
    declare -A ITER=([cornell-box]=500 [veach-ajar]=500 [statue]=2000)

    # The statue has no published reference: render one, unguided, with a seed no run uses.
    if ! grep -q '^total' "$STUDY/statue-reference.log" 2>/dev/null; then
        echo "rendering the statue reference (4096 spp)"
        "$TRACER" --scene "${SCENE[statue]}" ${SIZE[statue]} --reference-mode --spp 4096 \
            --seed 1000 --threads "$JOBS" --out "$STUDY/statue-reference" \
            >"$STUDY/statue-reference.log" 2>&1
    fi

    # One line per run: its name, then the tracer's arguments.
    joblist=$STUDY/jobs.txt
    : >"$joblist"
    # (xargs -L joins a line that ends in a blank with the next one: none may.)
    add() { local line="$*"; echo "${line%"${line##*[! ]}"}" >>"$joblist"; }
    # Every guided run follows the paper's protocol (nf_paper --variant paper), not the
    # equal-time defaults; extra arguments may name their own --variant list including it.
    guided() { # scene prior seed name-suffix extra-args...
        local scene=$1 prior=$2 seed=$3 suffix=$4 variant="--variant paper"
        shift 4
        case "$*" in *--variant*) variant="" ;; esac
        add "$scene-$prior$suffix-s$seed --scene ${SCENE[$scene]} ${SIZE[$scene]}" \
            "--reference ${REF[$scene]} --prior $prior --lr ${LR[$scene]}" \
            "--iterations ${ITER[$scene]} --eval-every 50 --eval-spp 4 --spp 32" \
            "--seed $seed $variant $*"
    }
    for seed in $SEEDS; do
        # Longest first, so that the pool drains evenly.
        for prior in uniform-direction cosine; do
            guided statue "$prior" "$seed" -large --model large          # Figure 4
        done
        for scene in statue cornell-box veach-ajar; do
            for prior in uniform-direction uniform-angle cosine; do   # Figures 1 and 2
                guided "$scene" "$prior" "$seed" ""
            done
            for eps in 0.001 0.1 0.25; do                             # the epsilon sweep
                guided "$scene" cosine "$seed" "-eps$eps" --variant "paper,prior-epsilon=$eps"
            done
        done
        guided veach-ajar bsdf "$seed" ""                               # the BSDF prior
        for prior in uniform-direction cosine; do                       # Figure 3, early
            add "statue-$prior-i500-s$seed --scene ${SCENE[statue]} ${SIZE[statue]}" \
                "--reference ${REF[statue]} --prior $prior --lr ${LR[statue]}" \
                "--iterations 500 --eval-every 0 --spp 32 --seed $seed --variant paper"
        done
        for scene in cornell-box veach-ajar statue; do                  # unguided, equal time
            for spp in 8 32 128 512; do
                add "$scene-unguided-spp$spp-s$seed --scene ${SCENE[$scene]} ${SIZE[$scene]}" \
                    "--reference ${REF[$scene]} --no-guiding --spp $spp" \
                    "--seed $seed"
            done
        done
    done

    echo "$(wc -l <"$joblist") runs, $JOBS at a time, in $RUNS"
    export TRACER RUNS
    # shellcheck disable=SC2016
    xargs -P "$JOBS" -L 1 bash -c '
        name=$0
        log=$RUNS/$name.log
        if grep -q "^total" "$log" 2>/dev/null; then exit 0; fi
        if "$TRACER" "$@" --threads 1 --out "$RUNS/$name" >"$log.tmp" 2>&1; then
            mv "$log.tmp" "$log"
            echo "done $name ($(grep "^total" "$log" | awk "{print \$2}") s)"
        else
            echo "FAILED $name: see $log.tmp" >&2
            exit 255
        fi' <"$joblist"
fi

python3 scripts/study/aggregate.py "$STUDY" docs/results
echo "paper-study.sh: tables and plots in docs/results/ ($(( $(date +%s) - start )) s)"
