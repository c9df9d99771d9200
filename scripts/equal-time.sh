#!/usr/bin/env bash
# The equal-time benchmark: renders each scene at fixed wall-clock budgets with plain path
# tracing and with the guided tracer (nf_tracer --time-budget: training included, scene
# loading excluded), measures relMSE and MAPE against converged references of our own, and
# regenerates docs/equal-time.md with its table, plots (docs/equal-time/*.png) and ablation.
#
# Usage (from the repository root, after ./scripts/install-deps.sh --study):
#   ./scripts/equal-time.sh            the whole study (its run time is in docs/equal-time.md)
#   ./scripts/equal-time.sh --smoke    about one minute: one scene, one short budget, one
#                                      seed, a tiny reference; checks that the pipeline runs
#                                      and writes its page to out/equal-time-smoke/ only
#
# Environment: NF_EQ_BUDGETS (seconds, default "10 30"), NF_EQ_SEEDS (default "1 2 3"),
# NF_EQ_SCENES (a scene of examples/scenes at its size below, or SCENE@WxH at another size),
# NF_EQ_REFERENCE_SECONDS (default 240 per scene), NF_EQ_ABLATION_BUDGET (default 30),
# NF_EQ_ABLATION_SCENES (default veach-ajar; empty: no ablation), NF_EQ_THREADS (default 2),
# NF_EQ_OUT (default out/equal-time), NF_EQ_PAGE and NF_EQ_PLOTS (default the page and plots
# of the scenes' set: docs/equal-time.md, or docs/equal-time-interiors.md when every scene
# is an interior), NF_EQ_TEMPLATE (default the page's).
#
# The interiors, at 1080p-like sizes and two budgets (run time in their page):
#   NF_EQ_SCENES="living-room modern-hall living-room@640x360 modern-hall@512x512" \
#   NF_EQ_BUDGETS="30 120" NF_EQ_REFERENCE_SECONDS=900 NF_EQ_ABLATION_SCENES= \
#   ./scripts/equal-time.sh
#
# References: each scene rendered once, unguided, for NF_EQ_REFERENCE_SECONDS with a seed no
# run uses, cached in $NF_EQ_OUT/references/ (delete them to render again). An entry whose
# size divides another entry's of the same scene by an integer factor uses that entry's
# reference, box-downsampled by nf_compare: one render serves both sizes. Runs are cached
# in $NF_EQ_OUT/runs/ the same way: a run whose log is complete is not run again, so an
# interrupted study resumes. Runs are one at a time, each with NF_EQ_THREADS threads: the
# machine should be otherwise idle. Not part of CI (CI runs --smoke).
set -euo pipefail

cd "$(dirname "$0")/.."
SMOKE=0
[ "${1:-}" = --smoke ] && SMOKE=1

BUDGETS=${NF_EQ_BUDGETS:-10 30}
SEEDS=${NF_EQ_SEEDS:-1 2 3}
SCENES=${NF_EQ_SCENES:-veach-ajar cornell-box veach-bidir statue}
REF_SECONDS=${NF_EQ_REFERENCE_SECONDS:-240}
ABLATION_BUDGET=${NF_EQ_ABLATION_BUDGET:-30}
THREADS=${NF_EQ_THREADS:-2}
OUT=${NF_EQ_OUT:-out/equal-time}
PAGE=docs/equal-time.md
PLOTS=docs/equal-time
ABLATION_SCENES=${NF_EQ_ABLATION_SCENES-veach-ajar}
TEMPLATE=${NF_EQ_TEMPLATE:-scripts/study/equal-time.md.in}
INTERIORS=1
for entry in $SCENES; do
    case ${entry%@*} in living-room|modern-hall) ;; *) INTERIORS=0 ;; esac
done
if [ "$INTERIORS" = 1 ] && [ -z "${NF_EQ_PAGE:-}" ]; then
    PAGE=docs/equal-time-interiors.md
    PLOTS=docs/equal-time-interiors
    TEMPLATE=${NF_EQ_TEMPLATE:-scripts/study/equal-time-interiors.md.in}
fi
PAGE=${NF_EQ_PAGE:-$PAGE}
PLOTS=${NF_EQ_PLOTS:-$PLOTS}
if [ "$SMOKE" = 1 ]; then
    BUDGETS=2
    SEEDS=1
    SCENES=cornell-box
    REF_SECONDS=4
    ABLATION_BUDGET=2
    ABLATION_SCENES=cornell-box
    OUT=out/equal-time-smoke
    TEMPLATE=scripts/study/equal-time.md.in
    PAGE=$OUT/equal-time.md
    PLOTS=$OUT/plots
fi
TRACER=build/examples/nf_tracer

for tool in gnuplot python3 cmake; do
    command -v "$tool" >/dev/null || {
        echo "equal-time.sh: '$tool' is missing; run ./scripts/install-deps.sh --study" >&2
        exit 1
    }
done

declare -A SIZE=([cornell-box]="--width 256 --height 256"
                 [veach-ajar]="--width 320 --height 180"
                 [veach-bidir]="--width 256 --height 256"
                 [statue]="--width 256 --height 256"
                 [living-room]="--width 320 --height 180"
                 [modern-hall]="--width 256 --height 256")

# An entry's scene and its size: SCENE, or SCENE@WxH.
scene_of() { echo "${1%@*}"; }
size_of() {
    case $1 in
        *@*) local wh=${1#*@}; echo "--width ${wh%x*} --height ${wh#*x}" ;;
        *) echo "${SIZE[$1]}" ;;
    esac
}

# The guided tracer as the study runs it: the tracer's defaults, which are the library's guide
# defaults (nisflow/guide.h) and the best configuration this study found.
GUIDED=""
# The ablation: one lever changed at a time from the defaults (nf_tracer --variant list),
# name|options.
ABLATION=(
    "plain path tracing|--no-guiding"
    "guided, the defaults|"
    "guiding probability 0.5|--variant guide-prob=0.5"
    "light samples weighed against the BSDF's density at every depth|--variant light-mis-bsdf"
    "light samples weighed against the mixture's density at every depth|--variant light-mis-depth=0"
    "only the first two vertices guided|--variant guide-depth=2"
    "normal and outgoing direction in the flow's input (4 SH bands)|--variant sh-bands=4"
    "smooth conductors guided too|--variant guide-min-roughness=0"
    "training weights clamped at the running 99th percentile|--variant clamp-quantile=0.99"
    "train up to 30 % of the budget|--variant train-fraction=0.3"
    "trained on all the emission found, not its MIS-weighted part|--variant all-emission"
    "passes one path at a time, the flow asked at shading points|--variant no-batching"
    "the mixture's boost over BSDF sampling not capped|--variant guide-max-boost=0"
)

start=$(date +%s)
mkdir -p "$OUT/references" "$OUT/runs" "$PLOTS"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j"$(nproc)" --target nf_tracer >/dev/null
[ -x "$TRACER" ] || { echo "equal-time.sh: $TRACER was not built" >&2; exit 1; }

# The commit the runs are made at (the first run's; cached runs keep theirs).
[ -f "$OUT/commit" ] || git rev-parse --short HEAD > "$OUT/commit" 2>/dev/null || true

# A run is complete when its log has the error line; $1 log, then the tracer's arguments.
run() {
    local log=$1
    shift
    if grep -q '^error' "$log" 2>/dev/null; then
        return 0
    fi
    "$TRACER" "$@" > "$log.tmp" 2>&1 || { cat "$log.tmp" >&2; exit 1; }
    tr '\r' '\n' < "$log.tmp" | grep -v '^\s*$' > "$log"
    rm -f "$log.tmp"
}

# The entry whose reference serves $1: the largest entry of the same scene whose width and
# height are the same integer multiple of $1's (possibly $1 itself).
reference_entry() {
    local best=$1 bw bh w h ew eh e
    read -r _ w _ h <<< "$(size_of "$1")"
    bw=$w
    for e in $SCENES; do
        [ "$(scene_of "$e")" = "$(scene_of "$1")" ] || continue
        read -r _ ew _ eh <<< "$(size_of "$e")"
        if [ $((ew % w)) = 0 ] && [ $((eh % h)) = 0 ] && [ $((ew / w)) = $((eh / h)) ] &&
            [ "$ew" -gt "$bw" ]; then
            best=$e
            bw=$ew
        fi
    done
    echo "$best"
}

for entry in $SCENES; do
    scene=$(scene_of "$entry")
    ref=$OUT/references/$entry.exr
    [ "$(reference_entry "$entry")" = "$entry" ] || continue
    if [ ! -f "$ref" ]; then
        echo "reference: $entry, unguided, ${REF_SECONDS} s"
        t0=$(date +%s)
        "$TRACER" --scene "examples/scenes/$scene/scene.xml" $(size_of "$entry") --no-guiding \
            --threads "$THREADS" --seed 999 --time-budget "$REF_SECONDS" \
            --out "$OUT/references/$entry" > "$OUT/references/$entry.log.tmp" 2>&1
        tr '\r' '\n' < "$OUT/references/$entry.log.tmp" | grep -v '^\s*$' \
            > "$OUT/references/$entry.log"
        rm -f "$OUT/references/$entry.log.tmp" "$OUT/references/$entry.png"
        echo "reference_seconds $(( $(date +%s) - t0 ))" >> "$OUT/references/$entry.log"
    fi
done
for entry in $SCENES; do
    big=$(reference_entry "$entry")
    if [ "$big" != "$entry" ] && [ ! -f "$OUT/references/$entry.exr" ]; then
        cp "$OUT/references/$big.exr" "$OUT/references/$entry.exr"
        echo "reference_of $big" > "$OUT/references/$entry.log"
    fi
done

for entry in $SCENES; do
    scene=$(scene_of "$entry")
    for budget in $BUDGETS; do
        for seed in $SEEDS; do
            for method in pt guided; do
                opts=$GUIDED
                [ "$method" = pt ] && opts=--no-guiding
                name=$entry-$budget-$seed-$method
                echo "run: $name"
                run "$OUT/runs/$name.log" --scene "examples/scenes/$scene/scene.xml" \
                    $(size_of "$entry") --threads "$THREADS" --seed "$seed" \
                    --time-budget "$budget" --reference "$OUT/references/$entry.exr" \
                    --out "$OUT/runs/$name" $opts
            done
        done
    done
done

: > "$OUT/ablation.list"
for scene in $ABLATION_SCENES; do
    for i in "${!ABLATION[@]}"; do
        label=${ABLATION[$i]%%|*}
        opts=${ABLATION[$i]#*|}
        for seed in $SEEDS; do
            name=ablation-$scene-$i-$seed
            echo "ablation: $scene, $label, seed $seed"
            run "$OUT/runs/$name.log" --scene "examples/scenes/$scene/scene.xml" \
                ${SIZE[$scene]} --threads "$THREADS" --seed "$seed" \
                --time-budget "$ABLATION_BUDGET" --reference "$OUT/references/$scene.exr" \
                --out "$OUT/runs/$name" $opts
            printf '%s\t%s\t%s\t%s\t%s\n' "$scene" "$i" "$seed" "$label" "$opts" \
                >> "$OUT/ablation.list"
        done
    done
done

NF_EQ_REFERENCE_SECONDS=$REF_SECONDS python3 scripts/study/equal_time.py --out "$OUT" \
    --page "$PAGE" --plots "$PLOTS" \
    --template "$TEMPLATE" \
    --budgets "$BUDGETS" --seeds "$SEEDS" --scenes "$SCENES" --ablation-budget "$ABLATION_BUDGET" \
    --guided "$GUIDED" --threads "$THREADS"
rm -f "$OUT"/runs/*.png
echo "wrote $PAGE ($(( $(date +%s) - start )) s)"
