#!/usr/bin/env bash
# The turnkey GPU run (issue 14): on one GPU and many cores, generate the data there, check the
# multi-GPU code path (torchrun + NCCL, one process), measure training speed and memory, train
# `small` then `base` in bf16 for fixed wall-clock budgets, and bench both on a fresh test split
# against the shipped reference and the classical baselines. Everything lands under $OUT:
#
#   $OUT/log.txt                    every command and its output
#   $OUT/speed.txt                  bench/bench_train.py: samples/s, s/step, peak GPU memory
#   $OUT/small-metrics.csv, $OUT/base-metrics.csv, $OUT/small.pt, $OUT/base.pt (exported checkpoints)
#   $OUT/bench.json, $OUT/bench.md  the test-split table
#
# On the device machine (docs/history/2026-11-log.md, "GPU training"): its python3 has torch with CUDA and every
# dependency but OpenEXR, which travels as a wheel (`make device-wheels` fills .whl/):
#
#   run(command="bash bench/device_run.sh", carry=[".whl"], timeout_s=560)
#
# SCALE=tiny runs every step on a CPU at tiny sizes (about 2.5 CPU-minutes; tests/test_scripts.py
# checks its commands and options).
set -euo pipefail
cd "$(dirname "$0")/.."
START=$SECONDS
OUT=${OUT:-build/device-out}
WORK=${WORK:-/tmp/projreg-device}
PY=${PY:-python3}
SCALE=${SCALE:-full}
mkdir -p "$OUT" "$WORK"
exec > >(tee -a "$OUT/log.txt") 2>&1

if compgen -G ".whl/*.whl" > /dev/null; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
CORES=$(nproc)
LOADERS=$(( CORES > 4 ? CORES - 2 : 1 ))

if [ "$SCALE" = tiny ]; then
  SIZE=48x64 TRAIN=(--pairs 1 --transforms 0-7) EVAL=(--pairs 1 --transforms 0-3)
  CROP=none PROBE_STEPS=3 SMALL_S=6 BASE_S=6 BATCH_SMALL=2 BATCH_BASE=2 LIMIT=4 MAX_STEPS=4 BENCH_SIZE=48x64
else
  SIZE=384x512 TRAIN=(--pairs 10) EVAL=(--pairs 1)
  CROP=256x320 PROBE_STEPS=30 SMALL_S=100 BASE_S=120 BATCH_SMALL=16 BATCH_BASE=8 LIMIT=64 MAX_STEPS=100000
  BENCH_SIZE=384x512
fi
projsynth() { $PY -m projsynth.cli "$@"; }
projreg() { $PY -m projreg.cli "$@"; }
stamp() { echo "== $(( SECONDS - START )) s: $*"; }

stamp "machine"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no GPU"
$PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"

stamp "data: train, val (seed 1) and a fresh test split (seed 8191), $CORES workers"
projsynth gen --out "$WORK/train" --split train --seed 1 --size "$SIZE" "${TRAIN[@]}" --workers "$CORES" --quiet
projsynth gen --out "$WORK/val" --split val --seed 1 --size "$SIZE" "${EVAL[@]}" --workers "$CORES" --quiet
projsynth gen --out "$WORK/test" --split test --seed 8191 --size "$BENCH_SIZE" "${EVAL[@]}" --workers "$CORES" --quiet

stamp "multi-GPU path: torchrun, one process (NCCL on a GPU, gloo on a CPU), $PROBE_STEPS steps of small"
rm -rf "$WORK/probe"
$PY -m torch.distributed.run --standalone --nproc_per_node 1 -m projreg.cli train --data "$WORK/train" \
  --out "$WORK/probe" --model small --steps "$PROBE_STEPS" --schedule-steps "$PROBE_STEPS" --warmup-steps 1 \
  --batch-size "$BATCH_SMALL" --crop "$CROP" --amp --no-activation-checkpointing --workers 4 --quiet
test -s "$WORK/probe/ddp_params.json" && cat "$WORK/probe/ddp_params.json" && echo

stamp "speed and memory (bench/bench_train.py)"
DEV=$($PY -c "import torch; print('cuda' if torch.cuda.is_available() else 'cpu')")
for run in "small --no-activation-checkpointing" "small" "base --no-activation-checkpointing"; do
  # shellcheck disable=SC2086  # model name and option
  $PY bench/bench_train.py --model $run --device "$DEV" --amp --batch "$BATCH_SMALL" --size "$SIZE" --steps 3 \
    --workers 2 | tee -a "$OUT/speed.txt"
done

steps_for() {  # model seconds: the steps that fit, at 80% of the measured samples/s (loader, validation)
  local rate
  rate=$(grep "result: model=$1 checkpointing=False" "$OUT/speed.txt" | sed 's/.*samples_per_s=\([0-9.]*\).*/\1/')
  $PY -c "import sys; r, s, b, top = map(float, sys.argv[1:]); print(max(2, min(int(top), int(0.8 * r * s / b))))" \
    "$rate" "$2" "$BATCH_SMALL" "$MAX_STEPS"
}
train() {  # model seconds batch
  local steps
  steps=$(steps_for "$1" "$2")
  steps=$(( steps * BATCH_SMALL / $3 ))
  stamp "train $1: $steps steps of batch $3 (budget $2 s)"
  rm -rf "$WORK/$1"
  projreg train --data "$WORK/train" --val "$WORK/val" --out "$WORK/$1" --model "$1" --steps "$steps" \
    --schedule-steps "$steps" --warmup-steps $(( steps / 20 + 1 )) --batch-size "$3" --crop "$CROP" --amp \
    --no-activation-checkpointing --val-every "$steps" --workers "$LOADERS" --quiet
  cp "$WORK/$1/metrics.csv" "$OUT/$1-metrics.csv"
  projreg export --checkpoint "$WORK/$1/checkpoints/last.pt" --out "$OUT/$1.pt"
}
train small "$SMALL_S" "$BATCH_SMALL"
train base "$BASE_S" "$BATCH_BASE"

stamp "bench on the fresh test split (network alone; the refinement is CPU work, measured on CPU)"
projreg bench --data "$WORK/test" --model reference --model "$OUT/small.pt" --model "$OUT/base.pt" --refine off \
  --baselines sift-ransac,dis-medium --limit "$LIMIT" --json "$OUT/bench.json" --markdown "$OUT/bench.md" --quiet
cat "$OUT/bench.md"
stamp "done"
