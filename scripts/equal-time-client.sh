#!/usr/bin/env bash
# The per-path client at equal time (docs/client.md, "The result"):
# examples/nf_guide_client.cpp renders its indirectly lit box with the library's schedule
# (training, guided or plain passes, the image) and with plain path tracing, seed by seed,
# back to back, and prints each run's relMSE against a long plain reference of its own and the
# ratio of the means.
#
# Usage (from the repository root, after building build/examples/nf_guide_client):
#   ./scripts/equal-time-client.sh            the study: reference, then 5 seeds at 20 s
#   ./scripts/equal-time-client.sh --smoke    about 30 s: a 10-s reference, one seed at 4 s
# Run time: NF_EQ_REFERENCE_SECONDS (400) once, then 2 x seeds x NF_EQ_SECONDS (20): about
# 10 minutes for 5 seeds. Environment: NF_EQ_SEEDS ("1 2 3 4 5"), NF_EQ_OUT
# (out/equal-time-client; the reference is kept there and reused). Run it alone on the
# machine: the ratios are only meaningful back to back.
set -euo pipefail
cd "$(dirname "$0")/.."
CLIENT=build/examples/nf_guide_client
SECONDS_PER_RUN=${NF_EQ_SECONDS:-20}
SEEDS=${NF_EQ_SEEDS:-1 2 3 4 5}
REF_SECONDS=${NF_EQ_REFERENCE_SECONDS:-400}
OUT=${NF_EQ_OUT:-out/equal-time-client}
if [ "${1:-}" = --smoke ]; then
    SECONDS_PER_RUN=4
    SEEDS=1
    REF_SECONDS=10
    OUT=out/equal-time-client-smoke
fi
[ -x "$CLIENT" ] || { echo "equal-time-client.sh: build $CLIENT first" >&2; exit 1; }
mkdir -p "$OUT"
REF=$OUT/reference-$REF_SECONDS.img
if [ ! -f "$REF" ]; then
    echo "reference: plain, $REF_SECONDS s, seed 999"
    "$CLIENT" --plain --seconds "$REF_SECONDS" --seed 999 --out "$REF" > "$OUT/reference.log"
fi
echo "client: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), 2 threads," \
    "$SECONDS_PER_RUN s a run, reference $REF_SECONDS s plain"
sum_g=0
sum_p=0
for seed in $SEEDS; do
    for kind in guided plain; do
        flag=
        [ "$kind" = plain ] && flag=--plain
        "$CLIENT" $flag --seconds "$SECONDS_PER_RUN" --seed "$seed" --reference "$REF" \
            > "$OUT/$kind-$seed.log"
        e=$(awk '/^relMSE/ { print $2 }' "$OUT/$kind-$seed.log")
        echo "seed $seed $kind relMSE $e: $(head -1 "$OUT/$kind-$seed.log")"
        [ "$kind" = guided ] && echo "    $(sed -n 2p "$OUT/$kind-$seed.log")"
        if [ "$kind" = guided ]; then sum_g=$(awk "BEGIN { print $sum_g + $e }"); else
            sum_p=$(awk "BEGIN { print $sum_p + $e }"); fi
    done
done
echo "guided / plain relMSE (means over seeds $SEEDS):" \
    "$(awk "BEGIN { printf \"%.3f\", $sum_g / $sum_p }")"
