#!/usr/bin/env bash
# The training-pass size study (docs/equal-time.md, "How large a training pass"): the per-path
# client (examples/nf_guide_client.cpp) at equal time with the guide's steps per training pass
# and samples per step varied, against plain path tracing, seed by seed, back to back.
#
# The client has no switch for them (the defaults won); this script builds a copy of the tree
# with docs/results/training-size/client-steps.patch applied, which reads NF_EXP_STEPS and
# NF_EXP_STEP_SAMPLES, in a temporary directory.
#
# Usage (from the repository root):
#   ./scripts/training-size-study.sh            the study: a 200-s plain reference, then
#                                               5 seeds x 6 settings x 20 s (about 14 minutes)
#   ./scripts/training-size-study.sh --smoke    about 1 minute: a 10-s reference, one seed at
#                                               4 s, two settings
# Output: one line per run, "seed setting relMSE", then each setting's mean and its ratio to
# plain's (docs/results/training-size/results.txt holds the study's lines). Run it alone on
# the machine.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_PER_RUN=20
REF_SECONDS=200
SEEDS="1 2 3 4 5"
SETTINGS="plain 64 32 128 64/1024 32/4096"
if [ "${1:-}" = --smoke ]; then
    SECONDS_PER_RUN=4
    REF_SECONDS=10
    SEEDS=1
    SETTINGS="plain 64"
fi
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
git archive HEAD | tar -x -C "$WORK"
patch -s -d "$WORK" -p1 < docs/results/training-size/client-steps.patch
cmake -S "$WORK" -B "$WORK/build" -DCMAKE_BUILD_TYPE=Release -DNF_BUILD_TESTS=OFF > /dev/null
cmake --build "$WORK/build" --target nf_guide_client -j2 > /dev/null
CLIENT=$WORK/build/examples/nf_guide_client
echo "client: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), 2 threads," \
    "$SECONDS_PER_RUN s a run, reference $REF_SECONDS s plain; setting = steps/samples per step"
"$CLIENT" --plain --seconds "$REF_SECONDS" --seed 999 --out "$WORK/ref.img" > /dev/null
: > "$WORK/runs.txt"
for seed in $SEEDS; do
    for s in $SETTINGS; do
        if [ "$s" = plain ]; then
            r=$("$CLIENT" --plain --seconds "$SECONDS_PER_RUN" --seed "$seed" --reference "$WORK/ref.img" | tail -1)
        else
            steps=${s%%/*}
            per=2048
            [[ $s == */* ]] && per=${s##*/}
            r=$(NF_EXP_STEPS=$steps NF_EXP_STEP_SAMPLES=$per "$CLIENT" --seconds "$SECONDS_PER_RUN" \
                --seed "$seed" --reference "$WORK/ref.img" | tail -1)
        fi
        echo "$seed $s ${r##* }" | tee -a "$WORK/runs.txt"
    done
done
awk '{sum[$2] += $3; n[$2]++} END {for (s in sum) printf "%-8s mean relMSE %.6f  ratio to plain %.3f\n", s, sum[s] / n[s], sum[s] / sum["plain"]}' "$WORK/runs.txt"
