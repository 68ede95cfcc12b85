"""Graph time of two (or more) exported models, interleaved step by step in one process.

    git show 84a559c:sdk/radar_odom/models/cart-0.4.onnx > prev-cart-0.4.onnx
    python benchmarks/compare_graphs.py prev-cart-0.4.onnx sdk/radar_odom/models/cart-0.4.onnx
    python benchmarks/compare_graphs.py cart-0.4@spin cart-0.4     # the previous session settings vs today's

This machine's load changes by tens of percent from one minute to the next, so timings taken
in separate runs do not compare; here every step runs each model once, in alternating order,
on the same sweep, each model with its own stream state. Prints the median, p10 and p90 per model
and each model's median (and p10: the least disturbed steps) ratio to the first. The models must
take the same sweep shape.
``--parity FRAMES``: also each model's largest pose difference from the first on simulated drives.
"""
from __future__ import annotations

import argparse
import sys
import time

SESSION_OPTIONS = {  # a model's ``@option`` suffix: onnxruntime settings other than the SDK's
    "spin": "intra-op workers spin between operators (onnxruntime's default; the SDK's before issue 43)",
    "basic": "graph optimisation level ORT_ENABLE_BASIC (the SDK's: ORT_ENABLE_ALL)",
}


def session(spec: str, threads: int):
    """An `OnnxModel` of ``spec``: a path or shipped name, optionally with ``@`` and comma-separated
    `SESSION_OPTIONS` (``cart-0.4@spin``: the shipped file as the previous release ran it)."""
    from radar_odom.model_zoo import pretrained, pretrained_names
    from radar_odom.onnx_model import OnnxModel

    name, _, opts = spec.partition("@")
    opts = {o for o in opts.split(",") if o}
    unknown = opts - set(SESSION_OPTIONS)
    if unknown:
        sys.exit(f"{spec}: unknown session options {sorted(unknown)}; known: {sorted(SESSION_OPTIONS)}")
    level = "basic" if "basic" in opts else None
    return OnnxModel(pretrained(name) if name in pretrained_names() else name, threads=threads,
                     spinning="spin" in opts, optimization=level)


def interleaved_times(models, steps: int = 300, warmup: int = 20, threads: int = 2) -> list[list[float]]:
    """Seconds per step of each model (paths or shipped names; stream form, one sweep shape), every step
    running each model once on the same sweep, in alternating order, each with its own stream state."""
    import numpy as np

    graphs = [session(m, threads) for m in models]
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


def pose_parity(models, seeds=(4242,), frames: int = 30, threads: int = 2,
                scenarios=("urban", "open")) -> list[tuple[float, float]]:
    """Largest |Δ translation| (m) and |Δ yaw| (rad) of each model's graph poses from the first's,
    over simulated drives (each seed × scenario, ``frames`` sweeps), every model with its own
    stream state and the same Cartesian inputs (`RadarOdometer.prepare`)."""
    import numpy as np

    from radar_odom import RadarOdometer
    from radar_odom.sim import simulate_drive

    odos = [RadarOdometer(session(m, threads)) for m in models]
    graphs = [o._model for o in odos]
    sweep, state_name = graphs[0].info.inputs
    worst = [(0.0, 0.0) for _ in models]
    for seed in seeds:
        for scenario in scenarios:
            states = [None] * len(models)
            for frame in simulate_drive(seed, frames, scenario):
                poses = []
                for i, (odo, g) in enumerate(zip(odos, graphs)):
                    x = odo.prepare(frame.scan).input
                    if x is None:
                        break
                    state = np.zeros(g.info.state_shape, np.float32) if states[i] is None else states[i]
                    out = g.run({sweep: x, state_name: state})
                    poses.append(None if states[i] is None else out["pose"].reshape(-1))
                    states[i] = out["state"]
                if len(poses) < len(models) or poses[0] is None:
                    continue
                for i, p in enumerate(poses):
                    d_xy = float(np.hypot(*(p[:2] - poses[0][:2])))
                    d_yaw = float(abs(p[2] - poses[0][2]))
                    worst[i] = (max(worst[i][0], d_xy), max(worst[i][1], d_yaw))
    return worst


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+",
                    help="exported .onnx files (stream form) or shipped names, each optionally with @ and "
                         "session options (" + "; ".join(f"{k}: {v}" for k, v in SESSION_OPTIONS.items()) +
                         "); the first is the reference")
    ap.add_argument("--steps", type=int, default=300, help="timed steps per model (default: %(default)s)")
    ap.add_argument("--warmup", type=int, default=20, help="untimed steps first (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default: %(default)s)")
    ap.add_argument("--parity", type=int, default=0, metavar="FRAMES",
                    help="also the largest pose difference from the first model over simulated urban and open "
                         "drives of FRAMES sweeps (default: 0, off)")
    args = ap.parse_args(argv)

    times = interleaved_times(args.models, args.steps, args.warmup, args.threads)
    import numpy as np

    ref = float(np.median(times[0]))
    print(f"{args.steps} steps each, interleaved, {args.threads} threads\n")
    ref10 = float(np.percentile(times[0], 10))
    print("| model | graph ms median | p10 | p90 | ratio to the first | p10 ratio |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, t in zip(args.models, times):
        t = np.asarray(t)
        p10 = np.percentile(t, 10)
        print(f"| {name} | {1e3 * np.median(t):.1f} | {1e3 * p10:.1f} | {1e3 * np.percentile(t, 90):.1f} | "
              f"{np.median(t) / ref:.2f} | {p10 / ref10:.2f} |")
    if args.parity:
        print(f"\nlargest pose difference from the first model, simulated urban + open drives, "
              f"{args.parity} sweeps each\n")
        print("| model | max Δ translation (mm) | max Δ yaw (rad) |")
        print("|---|---:|---:|")
        for name, (d_xy, d_yaw) in zip(args.models, pose_parity(args.models, frames=args.parity,
                                                                 threads=args.threads)):
            print(f"| {name} | {1e3 * d_xy:.3f} | {d_yaw:.2e} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
