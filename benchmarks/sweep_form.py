"""Step time of the sweep form against the SDK path, and per runtime, interleaved in one process.

    python benchmarks/sweep_form.py                       # cart-0.4 and cart-0.8, onnxruntime, 2 threads
    python benchmarks/sweep_form.py --runtimes onnxruntime,openvino --threads 1

A step is what a caller pays per sweep, from the sweep in memory (a `RadarScan`) to the pose:

* *SDK path*: `polar_to_cartesian` (OpenCV) + the shipped stream graph;
* *sweep form*: the sweep's arrays (`sweep_feeds`) + the sweep-form graph (the drawing inside;
  docs/sweep-form.md), built here from the shipped file (needs onnx).

This machine's load changes by tens of percent from one minute to the next, so every round runs each
variant once on the same simulated sweep (a short drive, cycled), in alternating order, each with its own
stream state. Prints the median and p90 per variant and its median ratio to the first row of its model
(the SDK path on onnxruntime). Needs onnx (the export extra); openvino for ``--runtimes ...openvino``.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path


def variants(names, runtimes, threads: int, folder: Path) -> list[tuple[str, str, str, object]]:
    """(model name, path kind, runtime, loaded model) for every shipped ``names`` × path × ``runtimes``."""
    import onnx

    import radar_odom
    from radar_odom.runtimes import load_model
    from radar_odom_export.sweep_form import wrap_stream_model

    out = []
    for name in names:
        stream = radar_odom.pretrained(name)
        sweep = folder / f"{name}-sweep.onnx"
        onnx.save(wrap_stream_model(stream), str(sweep))
        for runtime in runtimes:
            out.append((name, "SDK path", runtime, load_model(stream, runtime, threads)))
            out.append((name, "sweep form", runtime, load_model(sweep, runtime, threads)))
    return out


def interleaved_step_times(models, scans, rounds: int, warmup: int) -> list[list[float]]:
    """Seconds per step of each loaded model (stream or sweep form), each round running every model once on the
    same sweep (``scans`` cycled) in alternating order, each model chaining its own state."""
    import numpy as np

    from radar_odom.odometry.sweep_input import graph_input

    states = [np.zeros(m.info.state_shape, np.float32) for m in models]
    times = [[] for _ in models]
    order = list(range(len(models)))
    for r in range(warmup + rounds):
        scan = scans[r % len(scans)]
        for i in (order if r % 2 else order[::-1]):
            m = models[i]
            t0 = time.perf_counter()
            x = graph_input(scan, m.info)  # the SDK's Cartesian image, or the sweep form's arrays
            feeds = dict(x) if isinstance(x, dict) else {m.info.inputs[0]: x}
            feeds[m.info.inputs[-1]] = states[i]
            states[i] = m.run(feeds)["state"]
            if r >= warmup:
                times[i].append(time.perf_counter() - t0)
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", default="cart-0.4,cart-0.8", help="shipped names (default: %(default)s)")
    ap.add_argument("--runtimes", default="onnxruntime",
                    help="comma-separated, of radar_odom.runtimes.RUNTIMES: onnxruntime, openvino, "
                         "onnxruntime-openvino (default: %(default)s)")
    ap.add_argument("--rounds", type=int, default=200, help="timed rounds (default: %(default)s)")
    ap.add_argument("--warmup", type=int, default=10, help="untimed rounds first (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="inference threads (default: %(default)s)")
    ap.add_argument("--sweeps", type=int, default=8, help="simulated sweeps cycled (default: %(default)s)")
    args = ap.parse_args(argv)

    import numpy as np

    from radar_odom.sim import simulate_drive

    scans = [f.scan for f in simulate_drive(seed=4, frames=args.sweeps)]
    with tempfile.TemporaryDirectory() as folder:
        rows = variants(args.models.split(","), args.runtimes.split(","), args.threads, Path(folder))
        times = interleaved_step_times([r[3] for r in rows], scans, args.rounds, args.warmup)
    print(f"{args.rounds} rounds, interleaved, {args.threads} threads, {args.sweeps} simulated sweeps cycled\n")
    print("| model | input | runtime | step ms median | p90 | ratio to the SDK path on onnxruntime |")
    print("|---|---|---|---:|---:|---:|")
    ref = {}
    for (name, kind, runtime, _), t in zip(rows, times):
        med = float(np.median(t))
        ref.setdefault(name, med)
        print(f"| {name} | {kind} | {runtime} | {med * 1e3:.2f} | {np.percentile(t, 90) * 1e3:.2f} | "
              f"{med / ref[name]:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
