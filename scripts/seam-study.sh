#!/usr/bin/env bash
# The seam study (docs/results.md, "The seam"): what the seam at phi = 0 costs with each phi
# map, NF_PHI_INTERVAL (splines of [0, 1] onto itself) and NF_PHI_CIRCULAR (the default).
#
#   1. nf_seam_study: the small model trained online on a vMF lobe times the cosine, centred on
#      the seam against the same configuration turned to phi = pi; KL by quadrature after
#      100, 500 and 2000 steps, uniform-direction and cosine priors, kappa 20 and 200, SEEDS
#      seeds; once per phi map with the training directions drawn as a guided renderer draws
#      them (the guide's mixture of the flow and a diffuse BSDF), and once with the circular
#      map and every training direction drawn from the flow (--training flow).
#   2. The Cornell box and a copy turned by -90 degrees about the z axis, camera included (the
#      image is the same): the light, straight up (+y) from most shading points, then lies at
#      phi = 0 (+x), across the seam. Guided renders (cosine prior, 200 iterations, then
#      32 spp) at 128 x 128 with seeds 1 .. RENDER_SEEDS per phi map, their error against the
#      scene's reference, and per map the means, standard deviations and turned / upright.
#
# It writes out/seam/unit-MAP.md, out/seam/unit-circular-flow.md and out/seam/render.md and
# prints them. About 15 minutes on 2 cores with the defaults (16 seeds for the unit study, 4
# renders per scene and map).
#
#   scripts/seam-study.sh [SEEDS]        (default 16 for the unit study, 4 renders per scene)
#   scripts/seam-study.sh --smoke        one seed, short runs (CI: seconds)
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT=$(pwd)
OUT=out/seam
SMOKE=0
SEEDS=16
RENDER_SEEDS=4
UNIT=()
RENDER=(--width 128 --height 128 --iterations 200 --spp 32 --eval-every 0)
if [ "${1:-}" = --smoke ]; then
    SMOKE=1
    SEEDS=1
    RENDER_SEEDS=1
    UNIT=(--steps 10,20 --kappas 20)
    RENDER=(--width 16 --height 16 --iterations 4 --batch 256 --spp 2 --eval-every 0)
elif [ -n "${1:-}" ]; then
    SEEDS=$1
fi
for p in build/examples/nf_seam_study build/examples/nf_paper build/examples/nf_compare; do
    test -x "$p" || { echo "build first: cmake -S . -B build && cmake --build build -j2" >&2; exit 1; }
done
mkdir -p "$OUT"

# ---- 1. The unit study ---------------------------------------------------------------------
for run in interval:mixture circular:mixture circular:flow; do
    map=${run%:*} training=${run#*:}
    name=unit-$map
    [ "$training" = flow ] && name=unit-$map-flow
    build/examples/nf_seam_study --seeds "$SEEDS" --phi-map "$map" --training "$training" \
        "${UNIT[@]}" > "$OUT/$name.md"
    cat "$OUT/$name.md"
    echo
done

# ---- 2. The turned Cornell box ---------------------------------------------------------------
SRC=examples/scenes/cornell-box
TURNED=$OUT/cornell-box-turned
mkdir -p "$TURNED"
# Every shape and the camera turned by R_z(-90 deg): (x, y, z) -> (y, -x, z). Model paths are
# made absolute, so that the copy needs no files of its own.
sed -e "s#value=\"models/#value=\"$ROOT/$SRC/models/#" \
    -e 's#<shape type="ply">#<shape type="ply"><transform name="to_world"><rotate z="1" angle="-90"/></transform>#' \
    -e 's#<lookat origin="0, 1, 6.8" target="0, 1, 5.8" up="0, 1, 0"/>#<lookat origin="1, 0, 6.8" target="1, 0, 5.8" up="1, 0, 0"/>#' \
    "$SRC/scene.xml" > "$TURNED/scene.xml"
grep -q 'origin="1, 0, 6.8"' "$TURNED/scene.xml" || { echo "the camera was not turned" >&2; exit 1; }

{
    echo "| phi map | scene | seed | MAPE | relMSE |"
    echo "|---|---|---|---|---|"
} > "$OUT/render-rows.md"
for map in interval circular; do
    for scene in "$SRC" "$TURNED"; do
        name=$(basename "$scene")
        # The paper's protocol, which section 8 of docs/results.md measured, with the map.
        variant=paper
        [ "$map" = interval ] && variant=paper,phi-interval
        for ((s = 1; s <= RENDER_SEEDS; ++s)); do
            build/examples/nf_paper --scene "$scene/scene.xml" --prior cosine \
                --variant "$variant" "${RENDER[@]}" --seed "$s" --threads 2 \
                --out "$OUT/$map-$name-$s" > "$OUT/$map-$name-$s.log"
            read -r mape relmse < <(build/examples/nf_compare "$SRC/reference-tungsten.exr" \
                "$OUT/$map-$name-$s.exr" | awk '/^MAPE/ { print $2, $4 }')
            echo "| $map | $name | $s | $mape | $relmse |" >> "$OUT/render-rows.md"
        done
    done
done
{
    cat "$OUT/render-rows.md"
    echo
    echo "| phi map | upright relMSE | turned relMSE | turned / upright | upright MAPE | turned MAPE |"
    echo "|---|---|---|---|---|---|"
    for map in interval circular; do
        awk -F'|' -v map="$map" -v turned="$(basename "$TURNED")" '
            $2 ~ " " map " " {
                k = ($3 ~ " " turned " ") ? 1 : 0
                n[k]++; r[k] += $6; rr[k] += $6 * $6; e[k] += $5; ee[k] += $5 * $5
            }
            function sd(s, ss, c) { return c > 1 ? sqrt((ss - s * s / c) / (c - 1)) : 0 }
            END {
                printf "| %s | %.6f ± %.6f | %.6f ± %.6f | **%.3f** | %.5f ± %.5f | %.5f ± %.5f |\n",
                    map, r[0] / n[0], sd(r[0], rr[0], n[0]), r[1] / n[1], sd(r[1], rr[1], n[1]),
                    (r[1] / n[1]) / (r[0] / n[0]), e[0] / n[0], sd(e[0], ee[0], n[0]),
                    e[1] / n[1], sd(e[1], ee[1], n[1])
            }' "$OUT/render-rows.md"
    done
    echo
    echo "Guided renders (\`nf_paper --prior cosine --variant paper[,phi-interval] ${RENDER[*]} --seed S\`) against" \
        "\`$SRC/reference-tungsten.exr\` (box-downsampled by nf_compare); libnisflow at commit" \
        "$(git rev-parse --short HEAD 2>/dev/null || echo '?')."
} > "$OUT/render.md"
cat "$OUT/render.md"
[ "$SMOKE" = 1 ] && echo "smoke run: $OUT/unit-*.md and $OUT/render.md written"
exit 0
