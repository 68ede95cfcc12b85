#!/usr/bin/env bash
# Your own model end to end on simulated drives, small settings: train (3 min) -> export, which
# calibrates the covariance first (3 min) -> run on a held-out drive (README "Your own model").
# Needs the torch side: pip install torch==2.13.0 --extra-index-url https://download.pytorch.org/whl/cpu, then
# pip install -e ".[cli]" -e ./export in a checkout (radar-odom-export: train, calibrate, export).
#   bash examples/train_export_run.sh [WORKDIR]
set -euo pipefail
work="${1:-radar-odom-example}"
mkdir -p "$work"

# 1. train the masking network on the coarsest grid, two simulated training worlds, a 3-minute budget
#    (seed policy: training 1000-1999, validation 2000-2999, held-out evaluation 5000+)
radar-odom train -o "$work/model.pt" --profile cart-0.8 \
    --sim-seeds 1000-1001 --val-seeds 2000 --scenarios urban --frames 60 --minutes 3 --threads 1 --workers 1

# 2. one self-contained ONNX graph as the shipped models are: fast search, stream form, and a covariance
#    calibrated first on held-out simulated drives (`radar-odom calibrate`'s defaults; the d² table printed)
radar-odom export "$work/model.pt" -o "$work/model.onnx"

# 3. a held-out drive, then odometry over it with the torch-free runtime
radar-odom simulate "$work/drive" --seed 5001 --frames 80 --scenario urban
radar-odom run "$work/drive" --model "$work/model.onnx" -o "$work/run"
