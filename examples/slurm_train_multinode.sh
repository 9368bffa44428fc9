#!/usr/bin/env bash
# Train across several nodes with torchrun (c10d rendezvous): one torchrun per node, one process per GPU.
#
#   sbatch --nodes=2 --gpus-per-node=8 examples/slurm_train_multinode.sh
#
# Every rank reads its own slice of the sample stream; rank 0 writes the run directory, which must be
# on a filesystem every node sees (as must the data). Re-submitting with RESUME=1 continues the run.
# Outside Slurm (or to test it on one machine) set NNODES=1, NPROC_PER_NODE and HEAD=localhost.
#SBATCH --job-name=projreg-train
#SBATCH --ntasks-per-node=1
#SBATCH --time=08:00:00
set -euo pipefail

DATA=${DATA:-data/train}
VAL=${VAL:-data/val}
RUN=${RUN:-runs/base}
MODEL=${MODEL:-base}
STEPS=${STEPS:-15000}             # where this job stops (resume with a larger one to go on)
SCHEDULE=${SCHEDULE:-15000}       # the learning-rate schedule's length: keep it across resumes
WARMUP=${WARMUP:-100}
BATCH=${BATCH:-8}                 # per process
WORKERS=${WORKERS:-4}             # loader processes per rank
NNODES=${NNODES:-${SLURM_NNODES:-1}}
NPROC_PER_NODE=${NPROC_PER_NODE:-${SLURM_GPUS_PER_NODE:-1}}
HEAD=${HEAD:-$(scontrol show hostnames "${SLURM_JOB_NODELIST:?}" | head -n 1)}
PORT=${PORT:-29500}
EXTRA=${EXTRA:-}                  # e.g. "--amp" on GPUs with bf16, "--crop none" for tiny test data
LAUNCH=${LAUNCH:-srun}            # one torchrun per node; "env" runs it directly (one node)

RESUME_FLAG=()
if [ "${RESUME:-0}" = 1 ]; then RESUME_FLAG=(--resume); fi

# shellcheck disable=SC2086  # EXTRA is a list of options
$LAUNCH python -m torch.distributed.run --nnodes "$NNODES" --nproc-per-node "$NPROC_PER_NODE" \
  --rdzv-id "${SLURM_JOB_ID:-projreg}" --rdzv-backend c10d --rdzv-endpoint "$HEAD:$PORT" \
  -m projreg.cli train --data "$DATA" --val "$VAL" --out "$RUN" --model "$MODEL" --steps "$STEPS" \
  --schedule-steps "$SCHEDULE" --warmup-steps "$WARMUP" --batch-size "$BATCH" --workers "$WORKERS" --quiet $EXTRA "${RESUME_FLAG[@]}"
