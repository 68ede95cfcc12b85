"""Graph time of two (or more) exported models, interleaved step by step in one process.

    git show 84a559c:sdk/radar_odom/models/cart-0.4.onnx > prev-cart-0.4.onnx
    python benchmarks/compare_graphs.py prev-cart-0.4.onnx sdk/radar_odom/models/cart-0.4.onnx

This machine's load changes by tens of percent from one minute to the next, so timings taken
in separate runs do not compare; here every step runs each model once, in alternating order,
on the same sweep, each model with its own stream state. Prints the median and p90 per model
and each model's median ratio to the first. The models must take the same sweep shape.
"""
from __future__ import annotations

import argparse
import sys
import time


def interleaved_times(models, steps: int = 300, warmup: int = 20, threads: int = 2) -> list[list[float]]:
    """Seconds per step of each model (paths or shipped names; stream form, one sweep shape), every step
    running each model once on the same sweep, in alternating order, each with its own stream state."""
    import numpy as np

    from radar_odom.model_zoo import pretrained, pretrained_names
    from radar_odom.onnx_model import OnnxModel

    graphs = [OnnxModel(pretrained(m) if m in pretrained_names() else m, threads=threads) for m in models]
    sweep, state_name = graphs[0].info.inputs
    shape = graphs[0].info.input_shape
    if any(g.info.input_shape != shape or g.info.form != "stream" for g in graphs):
        sys.exit("the models must be stream-form graphs taking the same sweep shape")
    x = (np.random.default_rng(0).random(shape) ** 8).astype(np.float32)  # sparse, radar-like
    states = [np.zeros(g.info.state_shape, np.float32) for g in graphs]
    times = [[] for _ in graphs]
    order = list(range(len(graphs)))
    for step in range(warmup + steps):
        for i in (order if step % 2 else order[::-1]):
            t0 = time.perf_counter()
            states[i] = graphs[i].run({sweep: x, state_name: states[i]})["state"]
            if step >= warmup:
                times[i].append(time.perf_counter() - t0)
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+",
                    help="exported .onnx files (stream form) or shipped names; the first is the reference")
    ap.add_argument("--steps", type=int, default=300, help="timed steps per model (default: %(default)s)")
    ap.add_argument("--warmup", type=int, default=20, help="untimed steps first (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default: %(default)s)")
    args = ap.parse_args(argv)

    times = interleaved_times(args.models, args.steps, args.warmup, args.threads)
    import numpy as np

    ref = float(np.median(times[0]))
    print(f"{args.steps} steps each, interleaved, {args.threads} threads\n")
    print("| model | graph ms median | p90 | ratio to the first |")
    print("|---|---:|---:|---:|")
    for name, t in zip(args.models, times):
        t = np.asarray(t)
        print(f"| {name} | {1e3 * np.median(t):.1f} | {1e3 * np.percentile(t, 90):.1f} | {np.median(t) / ref:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
