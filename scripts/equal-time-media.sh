#!/usr/bin/env bash
# The equal-time comparison of the media scenes (docs/equal-time.md, "Participating media"):
# renders one scene at a fixed wall-clock budget with plain path tracing and with the guided
# tracer (nf_tracer --time-budget: training included, scene loading excluded), seed by seed,
# plain and guided back to back, and prints a table row of relMSE and MAPE against the
# scene's committed reference (examples/scenes/SCENE/reference.exr, README there).
#
# Usage (from the repository root, after building build/examples/nf_tracer):
#   ./scripts/equal-time-media.sh SCENE [BUDGET]     e.g. veach-ajar-fog 30
# Run time: 2 x seeds x BUDGET seconds plus scene loading (3.3 minutes for 3 seeds at 30 s).
# Environment: NF_EQ_SEEDS (default "1 2 3"), NF_EQ_THREADS (default 2), NF_EQ_OUT (default
# out/equal-time-media). Run it alone on the machine (for example under a lock that stops
# everything else): the ratios are only meaningful back to back.
set -euo pipefail
cd "$(dirname "$0")/.."
SCENE=${1:?usage: equal-time-media.sh SCENE [BUDGET]}
BUDGET=${2:-30}
SEEDS=${NF_EQ_SEEDS:-1 2 3}
THREADS=${NF_EQ_THREADS:-2}
OUT=${NF_EQ_OUT:-out/equal-time-media}
TRACER=build/examples/nf_tracer
REF=examples/scenes/$SCENE/reference.exr
case $SCENE in
    veach-ajar-fog) SIZE="--width 320 --height 180" ;;
    cornell-box-haze|cornell-box-plume) SIZE="--width 128 --height 128" ;;
    *) SIZE="--width 256 --height 256" ;;
esac
[ -x "$TRACER" ] || { echo "equal-time-media.sh: build $TRACER first" >&2; exit 1; }
[ -f "$REF" ] || { echo "equal-time-media.sh: no reference $REF" >&2; exit 1; }
mkdir -p "$OUT"
for seed in $SEEDS; do
    for method in pt guided; do
        opts=""
        [ "$method" = pt ] && opts=--no-guiding
        name=$SCENE-$BUDGET-$seed-$method
        "$TRACER" --scene "examples/scenes/$SCENE/scene.xml" $SIZE --threads "$THREADS" \
            --seed "$seed" --time-budget "$BUDGET" --reference "$REF" --out "$OUT/$name" \
            $opts 2>&1 | tr '\r' '\n' | grep -v '^\s*$' > "$OUT/$name.log"
        grep '^error' "$OUT/$name.log" | sed "s/^/$name: /"
    done
done
python3 - "$OUT" "$SCENE" "$BUDGET" "$SEEDS" <<'PY'
import re, statistics, sys
out, scene, budget, seeds = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4].split()
def errors(method):
    rel, mape = [], []
    for s in seeds:
        text = open(f"{out}/{scene}-{budget}-{s}-{method}.log").read()
        m = re.search(r"MAPE ([0-9.e+-]+), relMSE ([0-9.e+-]+)", text)
        mape.append(float(m.group(1)))
        rel.append(float(m.group(2)))
    return rel, mape
def cell(v):
    sd = statistics.stdev(v) if len(v) > 1 else 0.0
    return f"{statistics.mean(v):.3g} ± {sd:.2g}"
pr, pm = errors("pt")
gr, gm = errors("guided")
print(f"| {scene} | {budget} s | {cell(pr)} | {cell(gr)} | **{statistics.mean(gr) / statistics.mean(pr):.2f}** "
      f"| {cell(pm)} | {cell(gm)} | {statistics.mean(gm) / statistics.mean(pm):.2f} |")
PY
