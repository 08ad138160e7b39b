#!/bin/sh
# Snakemake 7's --cluster-status for Slurm: given the id that `sbatch --parsable` printed
# ("1234" or "1234;cluster"), prints `success`, `running` or `failed` for Snakemake to act on.
# Without it, Snakemake 7 waits for a job's output files and never learns that Slurm ended the
# job (time limit, memory, node failure, scancel): the case would not be marked failed.
#
# sacct (the accounting database) knows finished jobs; squeue (the controller) knows jobs from
# their submission on, before accounting may have them. Where sacct does not answer at all (the
# database down for a moment), the job counts as running and is asked about again.
job=${1%%;*}
if [ -z "$job" ]; then
    echo "usage: $0 JOBID" >&2
    exit 2
fi

# -X: the job's allocation, not its steps; -P -n: the bare state ("CANCELLED by 1234" for a
# job someone cancelled); a requeued job lists its latest state.
state=$(sacct -j "$job" -X -n -P -o State 2>/dev/null | head -n 1)
[ -n "$state" ] || state=$(squeue -j "$job" -h -o %T 2>/dev/null | head -n 1)
if [ -z "$state" ]; then
    if ! sacct -j "$job" -X -n -P -o State >/dev/null 2>&1; then
        echo "slurm-status: sacct does not answer about job $job; asking again later" >&2
        echo running
    else
        echo "slurm-status: neither sacct nor squeue knows job $job" >&2
        echo failed
    fi
    exit 0
fi
case ${state%% *} in
COMPLETED)
    echo success ;;
PENDING | CONFIGURING | RUNNING | COMPLETING | SUSPENDED | STOPPED | REQUEUED | REQUEUE_FED | REQUEUE_HOLD | \
    RESIZING | RESV_DEL_HOLD | SIGNALING | STAGE_OUT)
    echo running ;;
*)
    # FAILED, TIMEOUT, OUT_OF_MEMORY, CANCELLED, NODE_FAIL, PREEMPTED, BOOT_FAIL, DEADLINE,
    # REVOKED, SPECIAL_EXIT
    echo failed ;;
esac
