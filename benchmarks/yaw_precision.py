"""The yaw pull: does a matcher read small turns in full, or shrink them toward "no rotation"?

    python benchmarks/yaw_precision.py                          # shipped models, every part; ≈ 4 min
    python benchmarks/yaw_precision.py --parts curves --rates 0.5,1 --scenarios urban
    python benchmarks/yaw_precision.py --models cart-0.4 my-model.onnx --markdown yaw.md

Four parts (``--parts``), each a table; every model runs as `radar_odom.RadarOdometer` runs it,
``graph`` = the match alone (``motion_prior=False``, so the graph's own read-out shows) and
``defaults`` = the odometer's defaults (motion prior on):

* ``curves``: simulated drives on a steady bend (`DriveConfig.constant_curvature_per_m`, 10 m/s,
  4 Hz) at each ``--rates`` yaw rate (°/sweep) in each ``--scenarios`` world; after the bend's
  ramp-in, the estimated/true yaw (Σ est·true / Σ true²) and the share of pairs read as exactly
  0 yaw (`radar_odom.evaluation.metrics.EXACT_ZERO_RAD`). An unbiased matcher reads 1.00 and no zeros.
* ``common-turn``: both sweeps of a pair drawn turned by the same angle c (``--turns``, °; a
  frame turned about the sensor, `SweepMotion(frame_pose=(0, 0, c))`): the pair's relative
  motion does not change, so neither should its estimated yaw. Per pair, the spread (max − min)
  of the estimated yaw over c, on simulated curve pairs (seed 5150, pairs 34–39: 0.36–0.64 °),
  the real Oxford pair and ten real RADIATE pairs; the table gives the largest spread.
* ``radiate``: the shared RADIATE city drive against its GNSS/INS (`radar_odom.evaluation.reference.gnss_reference`:
  clock offset estimated from the default model's run, heading turned onto the track):
  KITTI-style error, step scale, yaw slope over pairs turning > 0.2°, exact-zero share.
* ``oxford``: the shared real Oxford pair (one pair, ground truth yaw +0.10°): estimated x and yaw.

``--centre-yaw`` runs the curves' and the RADIATE drive's model rows with ``RadarOdometer(centre_yaw=True)``
(`radar_odom.odometry.centring`); the reference's clock still comes from the default run.

The real sweeps (``../shared/data/real``) are read where they lie and never copied; the parts
that need them are skipped with a note where that folder is absent.
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
PARTS = ("curves", "common-turn", "radiate", "oxford")
OXFORD_PAIR, RADIATE_DRIVE = "oxford-2019-01-10-14-36-48", "radiate-2019-02-12-edinburgh"
SPEED_MPS = 10.0
RAMP_PAIRS = 4  # pairs at the start of a bend drive that are still on the lead-in or the ramp


def curve_scans(rate_deg: float, scenario: str, frames: int, seed: int):
    """(scans, true relative poses float64[frames − 1, 3]) of a simulated drive on a steady bend of
    ``rate_deg`` per sweep at `SPEED_MPS` (positive: turning right, +yaw)."""
    from radar_odom.sim.scenarios import steady_scenario
    from radar_odom.sim.simulator import simulate_drive

    frames_ = list(simulate_drive(seed, frames, steady_scenario(scenario, SPEED_MPS, rate_deg)))
    return [f.scan for f in frames_], np.array([f.pose_rel for f in frames_[1:]])


def run_odometer(model, scans, prior: bool, centre_yaw: bool = False):
    """The `RadarOdometer` (motion prior on or off, yaw centring on or off) after stepping through ``scans``,
    and its estimates."""
    from radar_odom import RadarOdometer

    odo = RadarOdometer(model, motion_prior=prior, centre_yaw=centre_yaw)
    return odo, [e for e in (odo.step(s) for s in scans) if e is not None]


def estimates(model, scans, prior: bool, centre_yaw: bool = False) -> np.ndarray:
    """float64[N − 1, 3] relative poses of the odometer over ``scans`` (the fused estimate with
    the prior, the graph's match without)."""
    return np.array([e.pose for e in run_odometer(model, scans, prior, centre_yaw)[1]])


def yaw_stats(gt: np.ndarray, est: np.ndarray) -> tuple[float, float]:
    """(estimated/true yaw, exact-zero share) of relative poses."""
    from radar_odom.evaluation.metrics import step_biases

    b = step_biases(gt, est, turning_deg=0.05)
    return b["yaw_slope"], b["exact_zero_share"]


def part_curves(models: dict, args) -> list[str]:
    lines = ["| model | read-out | scenario | " + " | ".join(f"{r:g} °/sweep" for r in args.rates) + " |",
             "|---|---|---|" + "---:|" * len(args.rates)]
    for scenario in args.scenarios:
        drives = {r: curve_scans(r, scenario, args.frames, args.seed) for r in args.rates}
        for name, model in models.items():
            for prior, label in ((False, "graph"), (True, "defaults")):
                cells = []
                for r in args.rates:
                    scans, gt = drives[r]
                    est = estimates(model, scans, prior, args.centre_yaw)
                    slope, zeros = yaw_stats(gt[RAMP_PAIRS:], est[RAMP_PAIRS:])
                    cells.append(f"{slope:.2f}" + (f" ({100 * zeros:.0f} % zeros)" if zeros else ""))
                lines.append(f"| {name} | {label} | {scenario} | " + " | ".join(cells) + " |")
                print(lines[-1], flush=True)
    return lines


def turned_yaws(model, first, second, turns_deg) -> np.ndarray:
    """float64[len(turns)]: the graph's relative yaw (rad) of ``second`` against ``first`` with both
    sweeps drawn in a frame turned by each common angle."""
    from radar_odom.odometry.sweep_input import SweepMotion, graph_input
    from radar_odom.onnx_model import OnnxModel

    graph = OnnxModel(model, threads=None)
    info = graph.info
    if info.form != "stream":
        raise SystemExit(f"{model}: the common-turn test runs stream-form models (this one is {info.form})")
    first_in, state_in = info.inputs
    zero = np.zeros(info.state_shape, dtype=np.float32)
    out = []
    for c in turns_deg:
        motion = SweepMotion(frame_pose=(0.0, 0.0, math.radians(c)))
        x0, x1 = graph_input(first, info, motion), graph_input(second, info, motion)
        state = graph.run({first_in: x0, state_in: zero})["state"]  # the first sweep's state, as a stream starts
        out.append(float(np.asarray(graph.run({first_in: x1, state_in: state})["pose"]).reshape(3)[2]))
    return np.array(out)


def common_turn_pairs(args):
    """{source: [(first, second), …]} for the common-turn test."""
    from radar_odom.io import read_sequence

    pairs = {}
    scans, _ = curve_scans_seed5150()
    pairs["simulated curve (seed 5150, pairs 34-39)"] = [(scans[i], scans[i + 1]) for i in range(34, 40)]
    oxford = real_recording(OXFORD_PAIR)
    if oxford is not None:
        s = [f.scan for f in read_sequence(oxford)]
        pairs["real Oxford pair"] = [(s[0], s[1])]
    radiate = real_recording(RADIATE_DRIVE)
    if radiate is not None:
        s = [f.scan for f in read_sequence(radiate)]
        pairs["real RADIATE pairs (sweeps 60, 80, …, 240)"] = [(s[i], s[i + 1]) for i in range(60, 241, 20)]
    return pairs


def curve_scans_seed5150():
    from radar_odom.sim.simulator import simulate_drive

    frames = list(simulate_drive(5150, 41, "urban"))
    return [f.scan for f in frames], np.array([f.pose_rel for f in frames[1:]])


def part_common_turn(models: dict, args) -> list[str]:
    lines = [f"| model | pairs | largest spread of the estimated yaw over common turns {args.turns} ° | mean spread |",
             "|---|---|---:|---:|"]
    sources = common_turn_pairs(args)
    for name, model in models.items():
        for source, pairs in sources.items():
            spreads = [np.ptp(np.degrees(turned_yaws(model, a, b, args.turns))) for a, b in pairs]
            lines.append(f"| {name} | {source} | {max(spreads):.3f} ° | {np.mean(spreads):.3f} ° |")
            print(lines[-1], flush=True)
    return lines


def real_recording(name: str) -> Path | None:
    """A shared real recording's folder, or None where ../shared/data/real lacks it."""
    path = REAL / name
    return path if path.is_dir() else None


def skipped(name: str) -> list[str]:
    return [f"(skipped: {REAL / name} is absent)"]


def part_radiate(models: dict, args) -> list[str]:
    from radar_odom import pretrained
    from radar_odom.evaluation.metrics import kitti_lengths_for, kitti_metrics, path_lengths_m, step_biases
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence
    from radar_odom.model_zoo import default_model_name
    from radar_odom.se2 import relative_from_absolute

    drive = real_recording(RADIATE_DRIVE)
    if drive is None:
        return skipped(RADIATE_DRIVE)
    seq = read_sequence(drive)
    scans = [f.scan for f in seq]
    default_run = run_odometer(pretrained(default_model_name()), scans, prior=True)[0]
    gt, _, note = gnss_reference(seq.reference, seq.timestamps_us, default_run.trajectory.poses)
    gt_rel = relative_from_absolute(gt)
    lengths = kitti_lengths_for(path_lengths_m(gt)[-1])
    lines = [note, "", "| model | read-out | translation % | rotation °/m | step scale | yaw slope | exact-zero yaw |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for name, model in models.items():
        for prior, label in ((False, "graph"), (True, "defaults")):
            est = run_odometer(model, scans, prior, args.centre_yaw)[0].trajectory.poses
            m = kitti_metrics(gt, est, step=4, lengths=lengths, pooling="segments")
            ok = np.all(np.isfinite(gt_rel), axis=1)
            b = step_biases(gt_rel[ok], relative_from_absolute(est)[ok])
            lines.append(f"| {name} | {label} | {m['translation_percent']:.2f} | {m['rotation_deg_per_m']:.4f} | "
                         f"{b['scale']:.3f} | {b['yaw_slope']:.3f} | {100 * b['exact_zero_share']:.1f} % |")
            print(lines[-1], flush=True)
    return lines


def part_oxford(models: dict, args) -> list[str]:
    import csv

    from radar_odom.io import read_sequence

    seq_dir = real_recording(OXFORD_PAIR)
    if seq_dir is None:
        return skipped(OXFORD_PAIR)
    row = next(csv.DictReader(open(seq_dir / "gt" / "radar_odometry.csv")))
    gx, gyaw = float(row["x"]), float(row["yaw"])
    scans = [f.scan for f in read_sequence(seq_dir)]
    lines = [f"truth: x {gx:.3f} m, yaw {math.degrees(gyaw):+.3f} °", "",
             "| model | x m (x / true) | yaw ° |", "|---|---:|---:|"]
    for name, model in models.items():
        est = estimates(model, scans, prior=False)[0]
        lines.append(f"| {name} | {est[0]:.3f} ({est[0] / gx:.3f}) | {math.degrees(est[2]):+.3f} |")
        print(lines[-1], flush=True)
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 epilog="The module docstring says what each part measures.")
    ap.add_argument("--models", nargs="*", default=None,
                    help="model names or .onnx files (default: every shipped model)")
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {PARTS} (default: all)")
    ap.add_argument("--rates", default="0.1,0.2,0.5,1,2,3", help="°/sweep (default: %(default)s)")
    ap.add_argument("--scenarios", default="urban,open", help="simulated worlds (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=28, help="sweeps per bend drive (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=5200, help="world seed of the bend drives (default: %(default)s)")
    ap.add_argument("--turns", default="0,0.2,0.4,0.6,0.8", help="common turns, ° (default: %(default)s)")
    ap.add_argument("--centre-yaw", action="store_true",
                    help="the model rows of the curves and radiate parts with RadarOdometer(centre_yaw=True) (each "
                         "sweep drawn turned by the predicted yaw; common-turn and Oxford have no prediction)")
    ap.add_argument("--markdown", type=Path, default=None, help="write the tables here too")
    args = ap.parse_args(argv)
    args.rates = [float(r) for r in args.rates.split(",")]
    args.scenarios = args.scenarios.split(",")
    args.turns = [float(t) for t in args.turns.split(",")]
    parts = args.parts.split(",")
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        ap.error(f"unknown parts {unknown}; choose from {PARTS}")
    from radar_odom import pretrained, pretrained_names

    names = args.models if args.models is not None else pretrained_names()
    models = {Path(n).name if n not in pretrained_names() else n:
              (pretrained(n) if n in pretrained_names() else Path(n)) for n in names}
    out = []
    for part in parts:
        t0 = time.perf_counter()
        print(f"== {part}", flush=True)
        lines = {"curves": part_curves, "common-turn": part_common_turn, "radiate": part_radiate,
                 "oxford": part_oxford}[part](models, args)
        out += [f"### {part}", "", *lines, "", f"({time.perf_counter() - t0:.0f} s)", ""]
    text = "\n".join(out)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
