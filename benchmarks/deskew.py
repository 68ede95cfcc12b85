"""De-skew off against on: simulated straight roads (the simulator's known motion distortion) and the real Oxford pair.

    python benchmarks/deskew.py                         # cart-0.4 and cart-0.8, 3 fresh seeds per scenario; ≈ 3 min
    python benchmarks/deskew.py --models cart-0.4 --seeds 10100 --frames 12   # ≈ 30 s

``sim``: straight roads at a constant speed (``--speeds``, one per scenario, default 10 m/s), one
drive per seed (fresh seeds, >= 10000: lower ones trained, calibrated or tuned something), every
model with `RadarOdometer` de-skew off and on, the motion prior off (the graph's own matches,
which is where a bias lives) and on (the defaults); and, as the floor de-skew could reach, the
same drives with frozen sweeps (every azimuth drawn from the ego pose at the sweep's mid time: no
motion distortion, the same noise and truth), de-skew off. The simulator draws every azimuth from
the ego pose at that azimuth's own timestamp, so its sweeps carry the distortion a spinning radar
has and de-skew is judged where the truth is known. Per row: the mean yaw error per sweep
(estimated − true, °, ± its standard error over the pairs: on a straight road the bias), the
same pairs' yaw error minus de-skew off's (Δ, paired, so its standard error is the comparison's),
the step scale (Σ estimated / Σ true forward step), the second step's x / true (the step the old
de-skew misread), the largest |x error| of any step (m), the reference redraws
(`RadarOdometer.reference_redraws`: one extra graph call each; a stream's first match adds one
more, its second match) and the wall time per sweep.

``oxford``: the shared real Oxford pair (``../shared/data/real/oxford-2019-01-10-14-36-48``, one
pair with ground truth, 0.865 m while braking): x, x / true, the distance from the truth and the
yaw, de-skew off and on (the defaults; the pair is a stream's first match, drawn again with the
velocity it measured). Then a diagnostic, not a method: the same pair matched by the graph with
the two sweeps drawn with different forward speeds, the reference faster than the new sweep by
the drop a constant deceleration would give over the interval (a constant-velocity de-skew
cannot know it from one pair).
``radiate-cost``: what de-skew costs on the shared RADIATE drive (280 sweeps; its accuracy, de-skew
off and on, is `benchmarks/real_drive.py`'s): the reference redraws (extra graph calls), the moving sampling
maps built and reused, and the wall time per sweep, the defaults: de-skew off, on with its maps rebuilt every
sweep (as before the map cache) and on, interleaved over ``--rounds`` rounds in one process.
The real sweeps are non-commercial data: read where they lie, never copied.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
OXFORD_PAIR = "oxford-2019-01-10-14-36-48"
PARTS = ("sim", "oxford", "radiate-cost")
RADIATE_DRIVE = "radiate-2019-02-12-edinburgh"
SKIP_PAIRS = 1  # the first pair has no velocity before it: left out of the bias and scale (it is in max |x err|)


def straight_scans(scenario: str, speed_mps: float, seed: int, frames: int, frozen: bool = False):
    """(scans, true relative poses float64[frames − 1, 3]) of a simulated straight road at a constant
    speed; ``frozen``: every azimuth drawn from the ego pose at the sweep's mid time (no motion during a
    sweep, traffic frozen too; the same timestamps, noise and truth), the distortion-free floor."""
    from radar_odom.sim.scenarios import steady_scenario
    from radar_odom.sim.simulator import Simulator

    class FrozenSimulator(Simulator):
        def drive_time_s(self, timestamps_us):  # render() draws at these times; pose_mid() takes their mean
            t = super().drive_time_s(timestamps_us)
            return np.full_like(t, t.mean()) if t.ndim else t

    frames_ = list((FrozenSimulator if frozen else Simulator)(seed, frames, steady_scenario(scenario, speed_mps)))
    return [f.scan for f in frames_], np.array([f.pose_rel for f in frames_[1:]])


def run(model, scans, deskew: bool, prior: bool):
    """(relative poses float64[N − 1, 3], reference redraws, s per sweep) of `RadarOdometer` over ``scans``."""
    from radar_odom import RadarOdometer

    odo = RadarOdometer(model, deskew=deskew, motion_prior=prior)
    t = time.perf_counter()
    est = [odo.step(s) for s in scans]
    per = (time.perf_counter() - t) / len(scans)
    return np.array([e.pose for e in est if e is not None]), odo.reference_redraws, per


def part_sim(models: dict, args) -> list[str]:
    lines = [f"seeds {', '.join(map(str, args.seeds))}; {args.frames} sweeps per drive; straight road, constant speed; "
             f"bias and scale over pairs {SKIP_PAIRS + 1}… of every drive; Δ: the same pairs' yaw error minus "
             "de-skew off's", "",
             "| model | scenario | prior | de-skew | yaw error ° / sweep (± s.e.) | Δ yaw error ° (± s.e.) | "
             "step scale | 2nd step x / true | max abs x err m | redraws / drive | ms / sweep |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    print("\n".join(lines), flush=True)
    variants = ((False, False, "off"), (False, True, "on"), (True, False, "frozen sweeps"))
    for scenario, speed in zip(args.scenarios, args.speeds):
        drives = {frozen: [straight_scans(scenario, speed, seed, args.frames, frozen) for seed in args.seeds]
                  for frozen in (False, True)}
        for name, model in models.items():
            for prior in (False, True):
                base = None
                for frozen, deskew, label in variants:
                    yaw_err, est_x, gt_x, second, worst, redraws, per = [], 0.0, 0.0, [], [], [], []
                    for scans, gt in drives[frozen]:
                        est, n_redraw, s_per = run(model, scans, deskew, prior)
                        yaw_err.append(np.degrees(est[SKIP_PAIRS:, 2] - gt[SKIP_PAIRS:, 2]))
                        est_x += est[SKIP_PAIRS:, 0].sum()
                        gt_x += gt[SKIP_PAIRS:, 0].sum()
                        second.append(est[1, 0] / gt[1, 0])
                        worst.append(np.abs(est[:, 0] - gt[:, 0]).max())
                        redraws.append(n_redraw)
                        per.append(s_per)
                    e = np.concatenate(yaw_err)
                    base = e if base is None else base
                    d = e - base
                    delta = "" if label == "off" else f"{d.mean():+.4f} (± {d.std(ddof=1) / math.sqrt(d.size):.4f})"
                    lines.append(
                        f"| {name} | {scenario} {speed:g} m/s | {'on' if prior else 'off'} | {label} | "
                        f"{e.mean():+.4f} (± {e.std(ddof=1) / math.sqrt(e.size):.4f}) | {delta} | {est_x / gt_x:.4f} | "
                        f"{np.mean(second):.3f} | {max(worst):.3f} | {np.mean(redraws):.1f} | "
                        f"{1e3 * np.mean(per):.0f} |")
                    print(lines[-1], flush=True)
    return lines


def part_oxford(models: dict, args) -> list[str]:
    from radar_odom.io import read_sequence
    from radar_odom.odometry.sweep_input import SweepMotion, graph_input
    from radar_odom.onnx_model import OnnxModel

    seq_dir = REAL / OXFORD_PAIR
    if not seq_dir.is_dir():
        return [f"{seq_dir}: not there (the shared real data?); part skipped"]
    seq = read_sequence(seq_dir)
    scans, gt = [f.scan for f in seq], np.asarray(seq.gt_relative[0])
    dt_s = (scans[1].timestamp_us - scans[0].timestamp_us) * 1e-6
    lines = [f"truth: x {gt[0]:.4f} m, y {gt[1]:+.4f} m, yaw {math.degrees(gt[2]):+.3f} °; interval {dt_s:.4f} s", "",
             "| model | de-skew | x m | x / true | distance from truth m | yaw ° | redraws |",
             "|---|---|---:|---:|---:|---:|---:|"]
    print("\n".join(lines), flush=True)
    for name, model in models.items():
        for deskew in (False, True):
            est, redraws, _ = run(model, scans, deskew, prior=True)
            p = est[0]
            lines.append(f"| {name} | {'on' if deskew else 'off'} | {p[0]:.4f} | {p[0] / gt[0]:.3f} | "
                         f"{np.hypot(*(p[:2] - gt[:2])):.3f} | {math.degrees(p[2]):+.3f} | {redraws} |")
            print(lines[-1], flush=True)
    lines += ["", "Diagnostic (the graph alone, both sweeps de-skewed forward, the reference faster by a·interval; "
              "mean speed the truth's x / interval):", "",
              "| model | deceleration a m/s² | reference / new sweep m/s | x m | x / true |",
              "|---|---:|---|---:|---:|"]
    print("\n".join(lines[-5:]), flush=True)
    v = gt[0] / dt_s
    for name, model in models.items():
        graph = OnnxModel(model, threads=None)
        info = graph.info
        first_in, state_in = info.inputs
        zero = np.zeros(info.state_shape, dtype=np.float32)
        for decel in args.decelerations:
            v0, v1 = v + 0.5 * decel * dt_s, v - 0.5 * decel * dt_s
            x0 = graph_input(scans[0], info, SweepMotion(twist=(v0, 0.0, 0.0)))
            x1 = graph_input(scans[1], info, SweepMotion(twist=(v1, 0.0, 0.0)))
            state = graph.run({first_in: x0, state_in: zero})["state"]
            x = float(np.asarray(graph.run({first_in: x1, state_in: state})["pose"]).reshape(3)[0])
            lines.append(f"| {name} | {decel:g} | {v0:.2f} / {v1:.2f} | {x:.4f} | {x / gt[0]:.3f} |")
            print(lines[-1], flush=True)
    return lines


def part_radiate_cost(models: dict, args) -> list[str]:
    """What de-skew costs on the shared RADIATE drive (its accuracy: benchmarks/real_drive.py): per model, de-skew
    off, on with its sampling maps rebuilt every sweep (the cache of moving maps emptied at once: how de-skew ran
    before the cache) and on as shipped, stepped interleaved for ``--rounds`` rounds in this one process; medians
    over the rounds and the ratio to de-skew off per round (median, range)."""
    import warnings

    from radar_odom import polar
    from radar_odom.io import read_sequence

    seq_dir = REAL / RADIATE_DRIVE
    if not seq_dir.is_dir():
        return [f"{seq_dir}: not there (the shared real data?); part skipped"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the drive's late stamps, put back on the period (real_drive.py says so)
        scans = [f.scan for f in read_sequence(seq_dir)]
    lines = [f"{len(scans)} sweeps, the defaults (motion prior on), {args.rounds} interleaved rounds", "",
             "| model | de-skew | reference redraws (extra graph calls) | moving maps built / reused per drive "
             "| ms / sweep (median) | ratio to off (median, range) |", "|---|---|---:|---:|---:|---:|"]
    print("\n".join(lines), flush=True)
    size = polar._MOVING_CACHE.size
    variants = (("off", False, size), ("on, maps rebuilt every sweep", True, 0), ("on", True, size))
    try:
        for name, model in models.items():
            per = {v[0]: [] for v in variants}
            redraws, maps = {}, {}
            for _ in range(args.rounds):
                for label, deskew, cache_size in variants:
                    polar.clear_map_cache()
                    polar._MOVING_CACHE.size = cache_size  # 0: every entry evicted at once, maps built per sweep
                    _, redraws[label], s_per = run(model, scans, deskew, prior=True)
                    info = polar.moving_map_cache_info()
                    maps[label] = f"{info['builds']} / {info['hits']}"
                    per[label].append(s_per)
            off = np.array(per["off"])
            for label, _, _ in variants:
                r = np.array(per[label]) / off
                lines.append(f"| {name} | {label} | {redraws[label]} | {maps[label]} "
                             f"| {1e3 * np.median(per[label]):.1f} "
                             f"| {np.median(r):.2f} ({r.min():.2f}-{r.max():.2f}) |")
                print(lines[-1], flush=True)
    finally:
        polar._MOVING_CACHE.size = size
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 epilog="The module docstring says what each part measures.")
    ap.add_argument("--models", nargs="*", default=["cart-0.4", "cart-0.8"], help="model names or .onnx files")
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {PARTS} (default: all)")
    ap.add_argument("--scenarios", default="urban,highway", help="simulated worlds (default: %(default)s)")
    ap.add_argument("--speeds", default="10,10", help="m/s, one per scenario (default: %(default)s)")
    ap.add_argument("--seeds", default="10100,10101,10102", help="fresh world seeds, >= 10000 (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=24, help="sweeps per drive (default: %(default)s)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of radiate-cost (default: %(default)s)")
    ap.add_argument("--decelerations", default="0,1,2", help="m/s², the Oxford diagnostic (default: %(default)s)")
    args = ap.parse_args(argv)
    args.scenarios = [s for s in args.scenarios.split(",") if s]
    args.speeds = [float(v) for v in args.speeds.split(",")]
    args.seeds = [int(v) for v in args.seeds.split(",")]
    args.decelerations = [float(v) for v in args.decelerations.split(",")]
    if len(args.speeds) != len(args.scenarios):
        ap.error(f"--speeds gives {len(args.speeds)} speeds for {len(args.scenarios)} scenarios; give one per scenario")
    if min(args.seeds) < 10000:
        ap.error("seeds below 10000 trained, calibrated or tuned something: judge de-skew on fresh ones (>= 10000)")
    if args.frames < 3:
        ap.error("--frames must be at least 3 (the bias leaves out the first pair)")
    parts = [p for p in args.parts.split(",") if p]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        ap.error(f"unknown part(s) {unknown}; choose from {PARTS}")
    from radar_odom import pretrained, pretrained_names

    models = {n: (pretrained(n) if n in pretrained_names() else Path(n)) for n in args.models}
    for part in parts:
        print(f"\n## {part}\n", flush=True)
        {"sim": part_sim, "oxford": part_oxford, "radiate-cost": part_radiate_cost}[part](models, args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
