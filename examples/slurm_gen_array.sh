#!/usr/bin/env bash
# Generate one projsynth dataset with a Slurm job array: every array task writes its own range of
# shards, then one dependent job writes the manifest.
#
#   sbatch --array=0-15 examples/slurm_gen_array.sh          # 16 tasks
#   sbatch --dependency=afterok:<array job id> --wrap "projsynth merge $OUT"
#
# Every task runs the same command with --shards TASK/TASKS, its contiguous share of the plan's shards
# (the shares differ by at most one shard); the samples do not depend on how the shards are split
# (same seed, same bytes). A task that is re-run resumes: finished shards are skipped. Outside Slurm (or to test this script) set SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT.
#SBATCH --job-name=projsynth-gen
#SBATCH --cpus-per-task=8
#SBATCH --time=02:00:00
set -euo pipefail

OUT=${OUT:-data/train}
PAIRS=${PAIRS:-64}                # image pairs; every pair gives 2 roles x the transforms
TRANSFORMS=${TRANSFORMS:-all}     # ids such as 0-15, or all (160)
SHARD_SIZE=${SHARD_SIZE:-64}
SIZE=${SIZE:-384x512}
SEED=${SEED:-0}
SPLIT=${SPLIT:-train}
TASK=${SLURM_ARRAY_TASK_ID:?run under sbatch --array, or set SLURM_ARRAY_TASK_ID}
TASKS=${SLURM_ARRAY_TASK_COUNT:?run under sbatch --array, or set SLURM_ARRAY_TASK_COUNT}

projsynth gen --out "$OUT" --pairs "$PAIRS" --transforms "$TRANSFORMS" --shard-size "$SHARD_SIZE" \
  --size "$SIZE" --seed "$SEED" --split "$SPLIT" --shards "$TASK/$TASKS" --workers "${SLURM_CPUS_PER_TASK:-1}" --quiet
