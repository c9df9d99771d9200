#!/usr/bin/env bash
# The point-cost study (docs/studies/cost-of-a-direction.md, "What a direction at a point
# costs"): what each step of one direction at a shading point (nf_point_sample, nf_point_pdf)
# costs, measured by replacing it with a trivial stand-in, and what three faster alternatives
# that change the results' bits would save.
#
# It exports the commit the patch was written for, BASE below (the single-direction code
# before nf_point_sample_and_pdf walked two directions in step, whose per-direction steps are
# the same operations), into a temporary directory, applies docs/results/point-cost/point-cost.patch
# (an NF_EXP bit mask selects the stand-ins and alternatives at compile time), builds nf_bench
# once per mask and times the small preset's point-sample, point-pdf and vertex on one thread,
# ROUNDS rounds of every mask back to back, reporting each mask's fastest round. The stand-ins'
# results are wrong by design: only their times mean anything. About 20 minutes on 2 cores
# (16 builds of a minute each, then 3 minutes of timing).
#
#   scripts/point-cost-study.sh [ROUNDS]     (default 3)
#   scripts/point-cost-study.sh --smoke      two masks, one short round (CI: about 2 minutes)
#
# Environment: NF_TIMER, a command prefix for each timed run (a wrapper that keeps other work
# off the CPU while it runs, say); NF_PC_BUILD, a directory that keeps the builds for the next
# run (default: a temporary one, removed at the end).
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT=$(pwd)
ROUNDS=3
REPS=(--reps 7)
MASKS=(0 1 2 4 8 16 32 64 128 256 512 1023 1024 2048 4096 7168)
if [ "${1:-}" = --smoke ]; then
    ROUNDS=1
    REPS=(--quick)
    MASKS=(0 4096)
elif [ -n "${1:-}" ]; then
    ROUNDS=$1
fi
declare -A WHAT=(
    [0]="today's code"
    [1]="stand-in: the inverse spline's root (nf_spline_bin_solve)"
    [2]="stand-in: the knot derivatives (softplus)"
    [4]="stand-in: the widths' and heights' exps"
    [8]="stand-in: the conditioner's output layer"
    [16]="stand-in: the direction to the square (two atan2)"
    [32]="stand-in: the API's checks (pointers, point, directions)"
    [64]="stand-in: the slope after the inverse"
    [128]="stand-in: the knots (sums and running sums)"
    [256]="stand-in: the prior's density"
    [512]="stand-in: the whole conditioner"
    [1023]="every stand-in above"
    [1024]="alternative: the inverse's root in float"
    [2048]="alternative: output layer on four partial sums"
    [4096]="alternative: knots, exps and softplus as whole vectors (K = 8)"
    [7168]="the three alternatives"
)
if [ -n "${NF_PC_BUILD:-}" ]; then
    TMP=$NF_PC_BUILD
    mkdir -p "$TMP"
else
    TMP=$(mktemp -d)
    trap 'rm -rf "$TMP"' EXIT
fi
SRC=$TMP/src-tree
BASE=2e73996
if ! git cat-file -e "$BASE^{commit}" 2>/dev/null; then
    echo "point-cost-study.sh: commit $BASE, which the patch applies to, is not in this clone" \
        "(a shallow clone?): fetch the history first"
    [ "$ROUNDS" = 1 ] && [ "${REPS[0]}" = --quick ] && exit 0 # the smoke run: nothing to check
    exit 1
fi
REV=$(git rev-parse --short "$BASE")
rm -rf "$SRC.new" && mkdir -p "$SRC.new"
git archive "$BASE" | tar -x -C "$SRC.new"
patch -s -d "$SRC.new" -p1 < "$ROOT/docs/results/point-cost/point-cost.patch"
# An unchanged tree keeps its files' times, so that kept builds stay up to date.
if [ -d "$SRC" ] && diff -r -q "$SRC" "$SRC.new" > /dev/null; then
    rm -rf "$SRC.new"
else
    rm -rf "$SRC" && mv "$SRC.new" "$SRC"
fi
for m in "${MASKS[@]}"; do
    cmake -S "$SRC" -B "$TMP/b$m" -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_C_FLAGS="-DNF_EXP=$m -Wno-psabi" > /dev/null
    cmake --build "$TMP/b$m" -j2 --target nf_bench > /dev/null
done
declare -A BEST
for r in $(seq "$ROUNDS"); do
    for m in "${MASKS[@]}"; do
        out=$(${NF_TIMER:-} "$TMP/b$m/bench/nf_bench" --preset small --threads 1 --op point-sample,point-pdf,vertex \
            "${REPS[@]}" --retries 0 --json "$TMP/b$m.json" 2>&1)
        for op in point-sample point-pdf vertex; do
            v=$(echo "$out" | awk -v op="$op" '$1 == "small" && $2 == op && $3 == "1T:" { print $4 }')
            [ -n "$v" ] || { echo "point-cost-study.sh: no $op figure from NF_EXP=$m:" >&2; echo "$out" >&2; exit 1; }
            key="$m/$op"
            if [ -z "${BEST[$key]:-}" ] || awk -v a="$v" -v b="${BEST[$key]}" 'BEGIN { exit !(a < b) }'; then
                BEST[$key]=$v
            fi
        done
    done
done
cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')
echo "| NF_EXP | what changes | point-sample ns | point-pdf ns | vertex ns | pdf saved ns |"
echo "|---|---|--:|--:|--:|--:|"
for m in "${MASKS[@]}"; do
    saved=$(awk -v a="${BEST[0/point-pdf]}" -v b="${BEST[$m/point-pdf]}" 'BEGIN { printf "%.0f", a - b }')
    echo "| $m | ${WHAT[$m]} | ${BEST[$m/point-sample]} | ${BEST[$m/point-pdf]} | ${BEST[$m/vertex]} | $saved |"
done
echo
echo "Fastest of $ROUNDS rounds, nf_bench --preset small --threads 1 --op point-sample,point-pdf,vertex ${REPS[*]}; $cpu; commit $REV."
