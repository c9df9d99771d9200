#!/usr/bin/env bash
# Long fuzzing of libnisflow's targets (docs/robustness.md, "Long fuzzing"): what CI's 60 s
# per target cannot reach. Builds the targets as .ci/robustness does (clang, libFuzzer, ASan +
# UBSan, `cmake -S fuzz -B build-fuzz`), runs each on one core (NF_FUZZ_FORK cores) for
# SECONDS with -fork=1 -ignore_crashes=1 -ignore_timeouts=1 -ignore_ooms=1 (so that one run
# gathers every distinct crash instead of stopping at the first), merges the inputs that add coverage into the
# committed corpus (fuzz/corpus/..., minimized with -merge=1), and prints executions, coverage
# and crashes per target. Crashing inputs are left in build-fuzz/long/artifacts/.
#
#   scripts/fuzz-long.sh [SECONDS]      SECONDS per target (default 600)
#
#   NF_FUZZ_TARGETS="a b=S ..."  a subset of the targets, each with an optional time of its own
#                         (e.g. "fuzz_deserialize=1100 fuzz_model_api=300")
#   NF_FUZZ_MERGE=0       do not merge new coverage into fuzz/corpus/
#   NF_FUZZ_FORK=2        run each target as 2 child processes, on 2 cores (default 1)
#   NF_JOBS=2             parallel build jobs
#
# How long: the build takes 1 to 4 minutes; then SECONDS per target, one after the other, on
# one core. The goal of at least 10 million executions per loader needs (rates measured on one
# core, docs/robustness.md) about 15 minutes for fuzz_deserialize (~11,500 exec/s), 2 hours
# for fuzz_model_api (~1,300/s), 2 hours for fuzz_point (~1,500/s), 22 minutes for
# fuzz_scene_load (~7,500/s), 2 minutes for fuzz_blocks (~92,000/s) and 30 minutes for
# fuzz_path (~5,700/s). A smoke run
# (`NF_FUZZ_MERGE=0 scripts/fuzz-long.sh 5`) takes the build plus about half a minute; it is
# not part of CI, whose .ci/robustness already runs every target for 60 s.
# Exit status: 0 when no target crashed, 1 otherwise.
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT=$(pwd)
SECS=${1:-600}
JOBS=-j${NF_JOBS:-2}
MERGE=${NF_FUZZ_MERGE:-1}
FORK=${NF_FUZZ_FORK:-1}
OUT=build-fuzz/long

command -v clang >/dev/null || { echo "clang is missing: run scripts/install-deps.sh" >&2; exit 1; }
CC=clang CXX=clang++ cmake -S fuzz -B build-fuzz > /dev/null
cmake --build build-fuzz "$JOBS"

# target:corpus directory (from the repository root):extra libFuzzer flags (.ci/robustness)
ALL_TARGETS=(
    "fuzz_deserialize:fuzz/corpus/model:"
    "fuzz_model_api:fuzz/corpus/model:"
    # fuzz_point: a feature counts as rare (the entropic scheduler's bookkeeping, per feature of
    # every execution) up to 32 hits instead of 255: faster, as much coverage
    # (docs/robustness.md, "fuzz_point's speed"; the header of fuzz/fuzz_point.c).
    "fuzz_point:fuzz/corpus/point:-entropic_feature_frequency_threshold=32"
    "fuzz_table:fuzz/corpus/table:"
    "fuzz_blocks:fuzz/corpus/blocks:"
    "fuzz_path:fuzz/corpus/path:"
    "fuzz_scene_load:examples/tracer/fuzz/corpus:-dict=$ROOT/examples/tracer/fuzz/scene.dict"
)

declare -A WANT=()
for w in ${NF_FUZZ_TARGETS:-}; do
    WANT[${w%%=*}]=$([[ $w == *=* ]] && echo "${w#*=}" || echo "$SECS")
done

mkdir -p "$OUT/artifacts"
RESULTS=()
CRASHED=0
for spec in "${ALL_TARGETS[@]}"; do
    IFS=: read -r name corpus flags <<< "$spec"
    secs=$SECS
    if [ -n "${NF_FUZZ_TARGETS:-}" ]; then
        [ -n "${WANT[$name]:-}" ] || continue
        secs=${WANT[$name]}
    fi
    if [ ! -x "build-fuzz/$name" ]; then
        echo "note: build-fuzz/$name was not built; skipping it"
        continue
    fi
    env_vars=(ASAN_OPTIONS="detect_leaks=1" UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1")
    if [ "$name" = fuzz_scene_load ]; then
        # As in .ci/robustness: the scene loader must survive malloc returning NULL.
        env_vars[0]="ASAN_OPTIONS=allocator_may_return_null=1:detect_leaks=1"
        flags="$flags -malloc_limit_mb=1048576"
    fi
    work="$OUT/corpus-$name"
    rm -rf "$work"
    mkdir -p "$work"
    cp "$corpus"/* "$work"/
    log="$OUT/$name.log"
    echo "--- $name: ${secs}s on $FORK core(s), corpus $corpus ($(find "$corpus" -type f | wc -l) files)"
    start=$SECONDS
    # shellcheck disable=SC2086 # flags is a list of flags
    env "${env_vars[@]}" "build-fuzz/$name" -fork="$FORK" -ignore_crashes=1 -ignore_timeouts=1 \
        -ignore_ooms=1 -max_total_time="$secs" -max_len=16384 -timeout=10 -rss_limit_mb=2048 \
        -artifact_prefix="$OUT/artifacts/$name-" $flags "$work" > "$log" 2>&1 || true
    took=$((SECONDS - start))
    # Fork mode reports "#<execs>: cov: <n> ft: <n> corp: <n> exec/s: <n> oom/timeout/crash:
    # <a>/<b>/<c> time: <s>s ..." lines; the last one holds the totals.
    last=$(grep -E '^#[0-9]+: cov:' "$log" | tail -n 1 || true)
    execs=$(sed -E 's/^#([0-9]+):.*/\1/' <<< "$last")
    cov=$(sed -nE 's/.* cov: ([0-9]+) ft: ([0-9]+).*/\1 \/ \2/p' <<< "$last")
    otc=$(sed -nE 's/.*oom\/timeout\/crash: ([0-9]+\/[0-9]+\/[0-9]+).*/\1/p' <<< "$last")
    crashes=$(find "$OUT/artifacts" -name "$name-*" -type f | wc -l)
    [ "$crashes" -gt 0 ] && CRASHED=1
    rate=$([ -n "$execs" ] && [ "$took" -gt 0 ] && echo $((execs / took)) || echo "?")
    added=0
    if [ "$MERGE" = 1 ]; then
        before=$(find "$corpus" -type f | wc -l)
        # shellcheck disable=SC2086
        env "${env_vars[@]}" "build-fuzz/$name" -merge=1 -max_len=16384 -timeout=10 \
            -rss_limit_mb=2048 $flags "$corpus" "$work" > "$OUT/$name.merge.log" 2>&1 || true
        added=$(($(find "$corpus" -type f | wc -l) - before))
    fi
    RESULTS+=("$(printf '%-18s %7s %13s %8s %15s %13s %8s %6s' "$name" "$took" "${execs:-?}" \
        "$rate" "${cov:-?}" "${otc:-?}" "$crashes" "$added")")
done

printf '\n%-18s %7s %13s %8s %15s %13s %8s %6s\n' target seconds executions "exec/s" \
    "cov / features" "oom/tmo/crash" "crashes" "merged"
printf '%s\n' "${RESULTS[@]+"${RESULTS[@]}"}"
echo "clang: $(clang --version | head -n 1); commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
if [ "$CRASHED" = 1 ]; then
    echo "crashes: see $OUT/artifacts/; reproduce with build-fuzz/<target> <file>" >&2
    exit 1
fi
