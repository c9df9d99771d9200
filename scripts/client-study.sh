#!/usr/bin/env bash
# The per-path client's studies (docs/client.md, "How large a training pass";
# docs/studies/cost-of-a-direction.md, "A per-path preset"): examples/nf_guide_client.cpp at
# equal time with one of the guide's or the model's settings varied, against plain path
# tracing, seed by seed, back to back.
#
# The client has no switch for them (the defaults won); this script builds a copy of the tree
# with scripts/study/client-knobs.patch applied, which reads NF_EXP_STEPS, NF_EXP_STEP_SAMPLES
# (the guide's steps per training pass and samples per step), NF_EXP_LAYERS, NF_EXP_BINS,
# NF_EXP_HIDDEN and NF_EXP_ONEBLOB (the model's coupling layers, spline bins, hidden width and
# one-blob bins), in a temporary directory.
#
# Usage (from the repository root):
#   ./scripts/client-study.sh training-size     a 200-s plain reference, then 5 seeds x 6
#                                               settings x 20 s (about 14 minutes)
#   ./scripts/client-study.sh model-size        the same with 7 model shapes (about 17 minutes)
#   ./scripts/client-study.sh NAME --smoke      about 1 minute: a 10-s reference, one seed at
#                                               4 s, plain and the default
# Output: one line per run, "seed setting client-line", then each setting's mean relMSE, its
# ratio to plain's, and a guided pass's mean variance and CPU time (docs/results/NAME/results.txt
# holds the studies' lines). Shapes other than the presets' run the library's general kernels,
# not the presets' vector ones: compare them by variance, not CPU. Run it alone on the machine.
set -euo pipefail
cd "$(dirname "$0")/.."
STUDY=${1:-}
case "$STUDY" in
training-size) SETTINGS="plain 64 32 128 64/1024 32/4096" ;;
model-size) SETTINGS="plain default oneblob=16 bins=4 bins=16 hidden=8 hidden=32 layers=4" ;;
*) echo "usage: $0 training-size|model-size [--smoke]" >&2; exit 2 ;;
esac
SECONDS_PER_RUN=20
REF_SECONDS=200
SEEDS="1 2 3 4 5"
if [ "${2:-}" = --smoke ]; then
    SECONDS_PER_RUN=4
    REF_SECONDS=10
    SEEDS=1
    SETTINGS="plain $([ "$STUDY" = training-size ] && echo 64 || echo default)"
fi

# A setting's environment: steps[/samples per step], or field=value of the model.
setting_env() {
    case "$1" in
    default) ;;
    layers=*) echo "NF_EXP_LAYERS=${1#*=}" ;;
    bins=*) echo "NF_EXP_BINS=${1#*=}" ;;
    hidden=*) echo "NF_EXP_HIDDEN=${1#*=}" ;;
    oneblob=*) echo "NF_EXP_ONEBLOB=${1#*=}" ;;
    */*) echo "NF_EXP_STEPS=${1%%/*} NF_EXP_STEP_SAMPLES=${1##*/}" ;;
    *) echo "NF_EXP_STEPS=$1" ;;
    esac
}

WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
git archive HEAD | tar -x -C "$WORK"
patch -s -d "$WORK" -p1 < scripts/study/client-knobs.patch
cmake -S "$WORK" -B "$WORK/build" -DCMAKE_BUILD_TYPE=Release -DNF_BUILD_TESTS=OFF > /dev/null
cmake --build "$WORK/build" --target nf_guide_client -j2 > /dev/null
CLIENT=$WORK/build/examples/nf_guide_client
echo "client: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), 2 threads," \
    "$SECONDS_PER_RUN s a run, reference $REF_SECONDS s plain; study $STUDY"
"$CLIENT" --plain --seconds "$REF_SECONDS" --seed 999 --out "$WORK/ref.img" > /dev/null
: > "$WORK/runs.txt"
for seed in $SEEDS; do
    for s in $SETTINGS; do
        if [ "$s" = plain ]; then
            r=$("$CLIENT" --plain --seconds "$SECONDS_PER_RUN" --seed "$seed" --reference "$WORK/ref.img" | tail -3 | tr "\n" " ")
        else
            # shellcheck disable=SC2046 # the settings are words without blanks
            r=$(env $(setting_env "$s") "$CLIENT" --seconds "$SECONDS_PER_RUN" --seed "$seed" \
                --reference "$WORK/ref.img" | tail -3 | tr "\n" " ")
        fi
        echo "$seed $s $r" | tee -a "$WORK/runs.txt"
    done
done
# Per setting: relMSE (mean, ratio to plain's), a guided pass's variance and CPU milliseconds.
awk '{
    sum[$2] += $NF; n[$2]++
    if (match($0, /variance [0-9.e+-]+ and/)) { v = substr($0, RSTART + 9, RLENGTH - 13); var[$2] += v }
    if (match($0, /guided \([0-9.]+ CPU ms/)) { c = substr($0, RSTART + 8, RLENGTH - 15); cpu[$2] += c }
} END {
    for (s in sum)
        printf "%-10s mean relMSE %.6f  ratio to plain %.3f  guided pass: variance %.3g, %.1f CPU ms\n",
            s, sum[s] / n[s], sum[s] / sum["plain"], var[s] / n[s], cpu[s] / n[s]
}' "$WORK/runs.txt"
