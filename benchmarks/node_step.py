"""Step time of the Node.js consumer (examples/node on onnxruntime-node) against the Python SDK, on the same
sweep-form graph and the same sweeps, back to back on this machine.

    python benchmarks/node_step.py                                  # cart-0.4, 2 threads, onnxruntime and openvino
    python benchmarks/node_step.py --runtimes onnxruntime --rounds 4 --steps 30

A step is the sweep in memory to the pose: in Node, the sweep's tensors and one run (``sweep_odometry.js --time``);
in Python, `graph_input` (the sweep form's arrays) and one run (benchmarks/sweep_form.py's step), each chaining
its own state. The two cannot share a process, so each round runs every variant once, a chunk of ``--steps``
timed steps after ``--warmup`` untimed ones (Node: a fresh process and session per chunk; Python: the models
loaded once), in alternating order. Prints the median and p90 of all timed steps per variant and, as the
machine's load moves between chunks, the median over rounds of each chunk's median as a ratio to the same
round's chunk of the first Python runtime. Needs node with examples/node installed (``npm ci``), onnx (the export extra)
and openvino for ``--runtimes ...openvino``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

NODE_DIR = Path(__file__).resolve().parents[1] / "examples" / "node"


def node_chunk(model: Path, pngs: list[Path], resolution_m: float, threads: int, steps: int, warmup: int) -> list:
    """Seconds per timed step of one ``sweep_odometry.js --time`` process."""
    cmd = ["node", str(NODE_DIR / "sweep_odometry.js"), str(model), *map(str, pngs), "--range-resolution-m",
           repr(resolution_m), "--threads", str(threads), "--time", str(steps), "--warmup", str(warmup)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return [ms / 1e3 for ms in json.loads(done.stdout)["step_ms"]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="cart-0.4", help="shipped name (default: %(default)s)")
    ap.add_argument("--runtimes", default="onnxruntime,openvino",
                    help="Python runtimes, comma-separated, of radar_odom.runtimes.RUNTIMES (default: %(default)s)")
    ap.add_argument("--rounds", type=int, default=6, help="rounds of one chunk per variant (default: %(default)s)")
    ap.add_argument("--steps", type=int, default=40, help="timed steps per chunk (default: %(default)s)")
    ap.add_argument("--warmup", type=int, default=5, help="untimed steps first in every chunk (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="inference threads (default: %(default)s)")
    ap.add_argument("--sweeps", type=int, default=8, help="simulated sweeps cycled (default: %(default)s)")
    args = ap.parse_args(argv)

    import numpy as np
    import onnx
    import onnxruntime

    import radar_odom
    from radar_odom import load_scan
    from radar_odom.runtimes import load_model
    from radar_odom.sim import write_drive
    from radar_odom_export.sweep_form import wrap_stream_model

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from sweep_form import interleaved_step_times

    node_version = subprocess.run(["node", "--version"], capture_output=True, text=True, check=True).stdout.strip()
    node_ort = json.loads((NODE_DIR / "node_modules" / "onnxruntime-node" / "package.json").read_text())["version"]
    runtimes = args.runtimes.split(",")
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        write_drive(folder / "drive", seed=4, frames=args.sweeps)
        pngs = sorted((folder / "drive" / "radar").glob("*.png"))
        scans = [load_scan(f) for f in pngs]
        model = folder / f"{args.model}-sweep.onnx"
        onnx.save(wrap_stream_model(radar_odom.pretrained(args.model)), str(model))
        loaded = {rt: load_model(model, rt, args.threads) for rt in runtimes}
        names = ["node", *runtimes]
        chunks = {n: [] for n in names}  # per round, the chunk's step times
        load = [os.getloadavg()[0]]
        for r in range(args.rounds):
            for name in (names if r % 2 == 0 else names[::-1]):
                if name == "node":
                    t = node_chunk(model, pngs, scans[0].range_resolution_m, args.threads, args.steps, args.warmup)
                else:
                    (t,) = interleaved_step_times([loaded[name]], scans, args.steps, args.warmup)
                chunks[name].append(t)
            load.append(os.getloadavg()[0])
    print(f"{args.model} sweep form, {args.threads} threads, {args.rounds} rounds × {args.steps} timed steps per "
          f"variant, {args.sweeps} simulated sweeps cycled; 1-min load average {min(load):.1f}–{max(load):.1f} on "
          f"{os.cpu_count()} CPUs")
    print(f"Node {node_version}, onnxruntime-node {node_ort}; Python onnxruntime {onnxruntime.__version__}\n")
    print(f"| consumer, runtime | step ms median | p90 | median over rounds: chunk ratio to Python {runtimes[0]} |")
    print("|---|---:|---:|---:|")
    ref = [np.median(t) for t in chunks[runtimes[0]]]
    for name in names:
        every = np.concatenate(chunks[name])
        ratio = np.median([np.median(t) / m for t, m in zip(chunks[name], ref)])
        label = "Node.js, onnxruntime-node" if name == "node" else f"Python SDK, {name}"
        print(f"| {label} | {np.median(every) * 1e3:.2f} | {np.percentile(every, 90) * 1e3:.2f} | {ratio:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
