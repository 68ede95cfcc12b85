"""Batched pairs: the sequence-form graph against the stream form, same process, same sweeps.

    python benchmarks/batch_throughput.py                 # the shipped cart-0.8 and cart-0.4; ~3 min

For each shipped model (or checkpoint, whose stream form is exported too): its sequence form is
exported once into ``--workdir`` (needs the export extra; an existing file is reused), simulated
urban sweeps are made into graph inputs once, and then, ``--repeats`` times in turn, the stream
graph steps through ``--pairs`` pairs and the sequence graph matches the same pairs in calls of
each ``--batch`` size. Printed per model and batch size: median and p90 over the repeats of ms per
pair, pairs/s, and the ratio of medians against the stream form measured in the same rounds. Graph
time only (inputs prepared before).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def graph_inputs(info, frames: int, seed: int) -> np.ndarray:
    from radar_odom.odometry.odometer import graph_input
    from radar_odom.sim.simulator import simulate_drive

    return np.stack([graph_input(f.scan, info)[0] for f in simulate_drive(seed, frames, "urban")])


def exported(name: str, workdir: Path, form: str) -> Path:
    """``name`` (a shipped name or a checkpoint .pt) exported with the fast search in ``form``
    into ``workdir`` (an existing file is reused)."""
    path = workdir / f"{Path(name).stem}-{'seq' if form == 'sequence' else 'fast'}.onnx"
    if not path.is_file():
        workdir.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "radar_odom", "export", name, "--form", form, "--search", "fast",
                        "-o", str(path)], check=True, stdout=subprocess.DEVNULL)
    return path


def time_stream(model, x: np.ndarray) -> float:
    info = model.info
    sweep, state_name = info.inputs
    state = model.run({sweep: x[:1], state_name: np.zeros(info.state_shape, np.float32)})["state"]
    t0 = time.perf_counter()
    for k in range(1, len(x)):
        state = model.run({sweep: x[k:k + 1], state_name: state})["state"]
    return (time.perf_counter() - t0) / (len(x) - 1)


def time_sequence(model, x: np.ndarray, batch: int) -> float:
    name = model.info.inputs[0]
    t0 = time.perf_counter()
    for c in range(0, len(x) - 1, batch):
        model.run({name: x[c:c + batch + 1]})
    return (time.perf_counter() - t0) / (len(x) - 1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="cart-0.8,cart-0.4",
                    help="shipped model names, or checkpoints (.pt: both forms are exported into --workdir)")
    ap.add_argument("--batch", default="4,8,16,32", help="pairs per sequence-graph call")
    ap.add_argument("--pairs", type=int, default=64, help="pairs timed per round")
    ap.add_argument("--repeats", type=int, default=7, help="rounds (stream and every batch size each)")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads")
    ap.add_argument("--workdir", default="batch-models", help="where the sequence-form files are exported")
    args = ap.parse_args(argv)
    from radar_odom import pretrained
    from radar_odom.onnx_model import OnnxModel

    batches = [int(b) for b in args.batch.split(",")]
    print("| model | form | pairs per call | ms per pair (median / p90) | pairs/s | ratio to stream |")
    print("|---|---|---:|---:|---:|---:|")
    for name in args.models.split(","):
        shipped = not name.endswith(".pt")
        stream_path = pretrained(name) if shipped else exported(name, Path(args.workdir), "stream")
        stream = OnnxModel(stream_path, threads=args.threads)
        seq = OnnxModel(exported(name, Path(args.workdir), "sequence"), threads=args.threads)
        name = Path(name).stem
        x = graph_inputs(stream.info, args.pairs + 1, seed=5000)
        time_stream(stream, x[:4]), time_sequence(seq, x[:9], 8)  # warm-up
        times = {0: []} | {b: [] for b in batches}
        for _ in range(args.repeats):
            times[0].append(time_stream(stream, x))
            for b in batches:
                times[b].append(time_sequence(seq, x, b))
        ref = float(np.median(times[0]))
        for b, t in times.items():
            med, p90 = 1e3 * float(np.median(t)), 1e3 * float(np.percentile(t, 90))
            form = "stream" if b == 0 else "sequence"
            print(f"| {name} | {form} | {1 if b == 0 else b} | {med:.1f} / {p90:.1f} | {1e3 / med:.1f} | "
                  f"{float(np.median(t)) / ref:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
