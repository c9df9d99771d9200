#!/usr/bin/env bash
# nf_paper and nf_tracer under mpirun (docs/distributed.md), registered with ctest as
# tracer_test_mpi when the tracer is built with MPI:
#   - nf_paper's image, model and CSV samples of 2 and 3 ranks equal one process's, bit for
#     bit, with 1 and 2 threads per rank;
#   - a rank whose scene is missing, whose options differ or whose model differs makes every
#     rank stop, with one message that names the rank and the cause;
#   - a rank killed by a signal ends the job instead of leaving the others waiting;
#   - nf_tracer's time-budgeted job on 2 ranks renders the image one process renders, within
#     noise.
# Every mpirun runs under `timeout`: a hang fails the test instead of stalling CI.
#
#   test_mpi.sh NF_TRACER NF_PAPER NF_COMPARE MPIEXEC SCENES_DIR WORK_DIR
set -u

TRACER=$1
PAPER=$2
COMPARE=$3
MPIEXEC=$4
SCENES=$5
WORK=$6/mpi-test
rm -rf "$WORK"
mkdir -p "$WORK"
cd "$WORK" || exit 1

# CI runs as root, which Open MPI refuses unless told; --oversubscribe lets 3 ranks share 2 cores.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
MPIRUN=("$MPIEXEC" --oversubscribe)
LIMIT=120

FAILED=0
check() { # check NAME CONDITION...: one line of the test's report
    local name=$1
    shift
    if "$@"; then
        echo "ok     $name"
    else
        echo "FAILED $name"
        FAILED=$((FAILED + 1))
    fi
}

SMALL=(--scene "$SCENES/cornell-box/scene.xml" --width 32 --height 32 --iterations 6
       --batch 700 --eval-every 3 --eval-spp 2 --spp 4)

# Runs a program on N ranks; rank-dependent words in the command are left to sh -c.
on_ranks() { # on_ranks N OUTPUT_PREFIX SHELL_COMMAND
    timeout "$LIMIT" "${MPIRUN[@]}" -n "$1" sh -c "$3" > "$2.out" 2> "$2.err"
}

# ---- The same model and image whatever the number of ranks and threads --------------------
"$PAPER" "${SMALL[@]}" --threads 2 --out one --save-model one.nf > one.out 2> one.err
check "one process renders" test -s one.exr -a -s one.nf
samples() { cut -d, -f1,2 "$1"; } # the CSV less its timing and MAPE columns

for config in "2 1" "2 2" "3 2"; do
    read -r n threads <<< "$config"
    name="ranks$n-threads$threads"
    timeout "$LIMIT" "${MPIRUN[@]}" -n "$n" "$PAPER" "${SMALL[@]}" --threads "$threads" \
        --out "$name" --save-model "$name.nf" > "$name.out" 2> "$name.err"
    check "$n ranks x $threads threads: exit status 0" test $? -eq 0
    check "$n ranks x $threads threads: the image equals one process's" cmp -s one.exr "$name.exr"
    check "$n ranks x $threads threads: the model equals one process's" cmp -s one.nf "$name.nf"
    check "$n ranks x $threads threads: the CSV's samples equal one process's" \
        cmp -s <(samples one.csv) <(samples "$name.csv")
    check "$n ranks x $threads threads: only rank 0 reports" \
        test "$(grep -c '^wrote .*\.exr' "$name.out")" -eq 1
done

# ---- Failures stop every rank, with the rank and the cause ---------------------------------
mkdir -p rank0 rank1
cp -r "$SCENES/cornell-box/." rank0/
# rank1/ has no scene: "the scene is not on this machine".
on_ranks 2 missing "cd rank\$OMPI_COMM_WORLD_RANK && exec '$PAPER' --scene scene.xml \
    --width 16 --height 16 --iterations 2 --batch 64 --eval-every 0 --spp 1 --out x"
status=$?
check "missing scene on rank 1: the job fails, no hang" test $status -ne 0 -a $status -ne 124
check "missing scene on rank 1: the message names rank 1" grep -q '^nf_paper: rank 1 of 2: ' missing.err
check "missing scene on rank 1: and the file" grep -q 'scene.xml' missing.err
check "missing scene on rank 1: said once" test "$(grep -c '^nf_paper: ' missing.err)" -eq 1

on_ranks 2 options "exec '$PAPER' ${SMALL[*]} --spp \$((4 + OMPI_COMM_WORLD_RANK)) --out o"
status=$?
check "different options: the job fails, no hang" test $status -ne 0 -a $status -ne 124
check "different options: the message names rank 1" \
    grep -q 'different options.*rank 1 differs from rank 0' options.err

"$PAPER" "${SMALL[@]}" --threads 2 --seed 7 --out other --save-model other.nf > /dev/null 2>&1
cp one.nf model0.nf
cp other.nf model1.nf
on_ranks 2 models "exec '$PAPER' ${SMALL[*]} --load-model model\$OMPI_COMM_WORLD_RANK.nf --out m"
status=$?
check "different models: the job fails, no hang" test $status -ne 0 -a $status -ne 124
check "different models: the message names rank 1" \
    grep -q 'models differ before training.*rank 1 differs from rank 0' models.err

# Rank 1 is killed by its CPU-time limit (SIGXCPU after 1 s) in the middle of a long training
# while rank 0 waits for it in a reduction: mpirun must end the job.
on_ranks 2 killed "if [ \$OMPI_COMM_WORLD_RANK = 1 ]; then ulimit -t 1; fi; exec '$PAPER' \
    --scene '$SCENES/cornell-box/scene.xml' --width 32 --height 32 --iterations 100000 \
    --batch 4096 --eval-every 0 --threads 1 --out k"
status=$?
check "rank 1 killed: the job ends with a failure, no hang (status $status)" \
    test $status -ne 0 -a $status -ne 124

# The time-budgeted job on 2 ranks: rank 0's clock decides, the image is both ranks' tiles.
# Its passes depend on the machine's speed, so it is compared with one process's render
# within noise: both estimate the same image; measured relMSE between them 3e-4 at 64 x 64
# and 4 s. The bound 0.005 leaves a slow machine's fewer passes room and still catches a
# missing or doubled share of the tiles (relMSE about 0.3).
BUDGET=(--scene "$SCENES/cornell-box/scene.xml" --width 32 --height 32 --time-budget 3
        --variant guide-depth=2)
"$TRACER" "${BUDGET[@]}" --threads 2 --out budget-one > budget-one.out 2> budget-one.err
timeout "$LIMIT" "${MPIRUN[@]}" -n 2 "$TRACER" "${BUDGET[@]}" --threads 1 --out budget \
    > budget.out 2> budget.err
check "--time-budget on 2 ranks: exit status 0" test $? -eq 0
check "--time-budget on 2 ranks: one report" test "$(grep -c '^budget ' budget.out)" -eq 1
relmse=$("$COMPARE" budget-one.exr budget.exr | awk '/^MAPE/ { print $4 }')
check "--time-budget on 2 ranks: the image matches one process's (relMSE ${relmse:-?})" \
    awk -v e="${relmse:-1}" 'BEGIN { exit !(e < 0.005) }'

if [ "$FAILED" -ne 0 ]; then
    echo "$FAILED checks failed; outputs in $WORK"
    for f in *.err; do [ -s "$f" ] && { echo "--- $f"; head -n 20 "$f"; }; done
    exit 1
fi
echo "all MPI checks passed"
