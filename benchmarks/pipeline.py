"""Does reading a recording overlap with the graph? Serial and pipelined runs of the same files, interleaved.

    python benchmarks/pipeline.py                  # cart-0.4, 40 sweeps a run, 4 rounds; ≈ 2 min on a quiet machine
    python benchmarks/pipeline.py --model cart-0.8 --sweeps 60 --rounds 6

A recording of simulated Oxford-layout PNG files is written to a temporary folder and streamed through
`radar_odom.iter_estimates` by fresh `RadarOdometer`s, in rounds; each round runs every configuration
once, in alternating order, so the machine's load falls on all of them alike:

* ``serial``: ``prefetch=0``, everything on the calling thread: its per-sweep medians of *read*
  (decode + parse + polar→Cartesian) and *step* (the graph) give the **serial sum**;
* ``pipelined``: the read-ahead worker thread (``prefetch=2``), as ``radar-odom run`` does;
* the same two with onnxruntime's workers spinning between operators (its default, and the SDK's
  before issue 43: `radar_odom.onnx_model.session_options`), and the pipelined run with one
  intra-op thread.

Prints, per configuration, the medians over rounds of wall time per sweep, read, step, and the ratio
of wall per sweep to the serial sum of the same round (≤ 0.85: the two stages overlap); the
spinning pipelined run is divided by the spinning serial sum.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

CONFIGS = {  # name: (intra-op threads, prefetch, spinning)
    "serial": (2, 0, False),
    "pipelined": (2, 2, False),
    "serial, spinning": (2, 0, True),
    "pipelined, spinning": (2, 2, True),
    "pipelined, 1 thread": (1, 2, False),
}


def run_once(model_path, paths, threads: int, prefetch: int, spinning: bool, warmup: int = 3) -> dict:
    """One run of ``paths`` through a fresh odometer: wall per sweep and the stages' medians (s)."""
    from radar_odom import RadarOdometer
    from radar_odom.latency.files import timed_stream
    from radar_odom.onnx_model import OnnxModel

    odo = RadarOdometer(OnnxModel(model_path, threads, spinning=spinning), max_gap_s=1e6)
    stream = timed_stream(paths, odo, warmup=warmup, prefetch=prefetch)
    return {"wall": stream.wall_s / stream.count, "read": statistics.median(stream.load_seconds),
            "step": statistics.median(stream.step_seconds)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="cart-0.4", help="shipped name or .onnx file (default: %(default)s)")
    ap.add_argument("--sweeps", type=int, default=40, help="sweeps per run (default: %(default)s)")
    ap.add_argument("--rounds", type=int, default=4, help="rounds of every configuration (default: %(default)s)")
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS),
                    help="configurations to run (default: all)")
    args = ap.parse_args(argv)

    from radar_odom.latency.files import write_recording
    from radar_odom.latency.sweeps import simulated_pngs
    from radar_odom.model_zoo import resolve_model

    model_path = resolve_model(args.model)
    results = {name: [] for name in args.configs}
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_recording(simulated_pngs(8), Path(tmp) / "radar", args.sweeps + 3)
        for r in range(args.rounds):
            round_ = {}
            for name in (args.configs if r % 2 == 0 else args.configs[::-1]):
                round_[name] = run_once(model_path, paths, *CONFIGS[name])
            for name, res in round_.items():
                serial = round_.get("serial, spinning" if "spinning" in name else "serial")
                res["ratio"] = res["wall"] / (serial["read"] + serial["step"]) if serial else float("nan")
                results[name].append(res)
    print(f"{args.model}, {args.sweeps} sweeps a run, {args.rounds} rounds interleaved; "
          "ms per sweep, medians over rounds\n")
    print("| configuration | wall per sweep | read | step | read + step | wall / serial sum (same round) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, runs in results.items():
        med = {k: statistics.median(r[k] for r in runs) for k in ("wall", "read", "step", "ratio")}
        print(f"| {name} | {1e3 * med['wall']:.1f} | {1e3 * med['read']:.1f} | {1e3 * med['step']:.1f} | "
              f"{1e3 * (med['read'] + med['step']):.1f} | {med['ratio']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
