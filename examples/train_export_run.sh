#!/usr/bin/env bash
# Train -> calibrate -> export -> run, end to end on simulated drives, with small settings
# (a few minutes on 2 CPU cores; the shipped models were trained far longer, see README).
# Needs the export extra: pip install "radar-odom[export,cli]".
#   bash examples/train_export_run.sh [WORKDIR]
set -euo pipefail
work="${1:-radar-odom-example}"
mkdir -p "$work"

# 1. train the masking network on the coarsest grid, on two simulated training worlds
#    (seed policy: training 1000-1999, validation 2000-2999, held-out evaluation 5000+)
radar-odom train -o "$work/model.pt" --profile cart-0.8 \
    --sim-seeds 1000-1001 --val-seeds 2000 --scenarios urban --frames 60 \
    --epochs 2 --steps-per-epoch 20 --minutes 5

# 2. tune the covariance temperature on a held-out validation world (mean d^2 -> 3)
radar-odom calibrate "$work/model.pt" --sim-seeds 2500 --scenarios urban --frames 60

# 3. one self-contained ONNX graph (stream form: sweep + previous state in, pose + covariance out)
radar-odom export "$work/model.pt" -o "$work/model.onnx"

# 4. a held-out drive, then odometry over it with the torch-free runtime
radar-odom simulate "$work/drive" --seed 5001 --frames 80 --scenario urban
radar-odom run "$work/drive" --model "$work/model.onnx" -o "$work/run"
