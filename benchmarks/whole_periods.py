"""Whole periods the stamps cannot tell apart, decided by the match (`radar_odom.odometry.whole_periods`).

    python benchmarks/whole_periods.py                       # ≈ 2 min on 2 cores
    python benchmarks/whole_periods.py --seeds 10040-10041 --speeds 10 --cases straight
    python benchmarks/whole_periods.py --gap 3 --cases straight,bend --speeds 10   # 3 sweeps dropped

Each case is a short simulated drive (`radar_odom.sim`, fresh seeds ≥ 10000) stamped the way a
recording host stamps it (`radar_odom.sim.host_stamps`, jitter ±4 ms), read through the time base
(`radar_odom.io.timebase.fit_time_base`, no period hint), then run by `RadarOdometer` (cart-0.4):

* ``straight`` (urban road at ``--speeds`` m/s) and ``bend`` (6 m/s turning 3° a sweep): the sweep
  ``AT`` is stamped one of two ways that give the same stamps: ``drop`` (sweep AT dropped, the next
  stamped on time) or ``late`` (sweep AT stamped a whole period late, sweep AT+1 dropped). The fit
  reads both as ``drop``.
* ``half``: every other sweep dropped for the whole drive (every interval two periods, P = 0.5 s or
  0.25 s from the stamps alone).

Methods: ``match`` passes the time base (``RadarOdometer(time_base=)``: the match decides);
``stamps`` passes only its period (``sweep_period_s=``: the fit's reading, as before). Per case,
speed, truth and method: how many of the seeds end with every sweep index k equal to the truth, how
many ambiguous sweeps stayed undecided, and the largest error of the two steps beside the ambiguous
sweep (``half``: of every step) against the simulator's truth (translation m, yaw °), median over
seeds, and the largest error of the velocity those steps imply (m/s; the time is part of it).
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "sdk"))

FRESH_SEED = 10000  # seeds below this trained, calibrated or tuned something
AT = 8  # the ambiguous sweep: the period and the velocity are known by then
FRAMES = 14
JITTER_US = 4_000.0


def drive(seed: int, frames: int, speed_mps: float, turn_deg: float = 0.0):
    """(scans, true absolute poses float64[N, 3, 3]) of a simulated urban drive."""
    from radar_odom.se2 import chain_relative
    from radar_odom.sim.scenarios import get_scenario
    from radar_odom.sim.simulator import simulate_drive

    base = get_scenario("urban")
    cfg = replace(base.drive, constant_speed_mps=speed_mps)
    if turn_deg:
        cfg = replace(cfg, constant_curvature_per_m=math.radians(turn_deg) / (speed_mps * 0.25))
    fr = list(simulate_drive(seed, frames, replace(base, drive=cfg)))
    return [f.scan for f in fr], chain_relative(np.array([f.pose_rel for f in fr[1:]]))


def stamped_case(scans, truth: str, seed: int, gap: int = 1):
    """(kept sweep indices, their host stamps µs) of one case: ``drop`` (sweeps AT … AT+gap−1 dropped),
    ``late`` (AT … AT+gap−2 dropped, AT+gap−1 stamped a period late, AT+gap dropped: the same stamps)
    or ``half``."""
    from radar_odom.sim.host_stamps import host_stamps

    true_us = np.array([s.timestamp_us for s in scans])
    period = int(np.median(np.diff(true_us)))
    if truth == "half":
        keep = list(range(0, len(scans), 2))
        return keep, host_stamps(true_us, keep, None, JITTER_US, seed)
    dropped = set(range(AT, AT + gap)) if truth == "drop" else set(range(AT, AT + gap - 1)) | {AT + gap}
    keep = [k for k in range(len(scans)) if k not in dropped]
    late = {AT + gap - 1: period} if truth == "late" else None
    return keep, host_stamps(true_us, keep, late, JITTER_US, seed)


def run_case(model, scans, poses, keep, stamps, method: str, every_step: bool = False):
    """(every k right, undecided, worst step error m, worst yaw error °, worst velocity error m/s)."""
    from radar_odom.io.timebase import fit_time_base
    from radar_odom.odometry.odometer import RadarOdometer
    from radar_odom.se2 import invert, to_xyyaw
    from radar_odom.sim.host_stamps import timed

    tb = fit_time_base(stamps)
    extra = {"time_base": tb} if method == "match" else {"sweep_period_s": tb.period_s}
    odo = RadarOdometer(model, threads=1, **extra)
    fed = timed([scans[k] for k in keep], tb.times_us)
    ests = [odo.step(s) for s in fed][1:]
    got = odo.time_base if method == "match" else tb
    true_k = np.asarray(keep) - keep[0]
    k_right = bool(np.array_equal(got.sweep_index, true_k))
    # the time the odometer used for each sweep against the truth, and the steps
    true_t = np.array([scans[k].timestamp_us for k in keep]) * 1e-6
    used_t = np.asarray(odo.trajectory.timestamps_us) * 1e-6
    # the steps into and out of the ambiguous sweep (kept position AT either way); ``half``: every step
    rows = range(len(ests)) if every_step else [AT - 1, AT]
    t_err, yaw_err, v_err = [], [], []
    for j in rows:
        truth = to_xyyaw(invert(poses[keep[j]]) @ poses[keep[j + 1]])
        e = ests[j].pose
        t_err.append(math.hypot(e[0] - truth[0], e[1] - truth[1]))
        yaw_err.append(abs(math.degrees(math.atan2(math.sin(e[2] - truth[2]), math.cos(e[2] - truth[2])))))
        v_err.append(abs(math.hypot(*e[:2]) / (used_t[j + 1] - used_t[j])
                         - math.hypot(*truth[:2]) / (true_t[j + 1] - true_t[j])))
    return k_right, len(got.alternatives), max(t_err), max(yaw_err), max(v_err)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="10040-10045", help="first-last (fresh: >= 10000)")
    ap.add_argument("--speeds", default="2,5,10,15", help="m/s of the straight case")
    ap.add_argument("--cases", default="straight,bend,half")
    ap.add_argument("--model", default="cart-0.4")
    ap.add_argument("--gap", type=int, default=1, help="sweeps dropped in the straight and bend cases")
    args = ap.parse_args(argv)
    import radar_odom

    lo, hi = (int(v) for v in args.seeds.split("-"))
    if lo < FRESH_SEED:
        ap.error(f"seeds must be fresh (>= {FRESH_SEED})")
    seeds = list(range(lo, hi + 1))
    model = radar_odom.pretrained(args.model)
    runs = []
    for case in args.cases.split(","):
        settings = ([(float(v), 0.0) for v in args.speeds.split(",")] if case == "straight"
                    else [(6.0, 3.0)] if case == "bend" else [(8.0, 0.0)])
        truths = ("half",) if case == "half" else ("drop", "late")
        for speed, turn in settings:
            for truth in truths:
                rows = {m: [] for m in ("match", "stamps")}
                for seed in seeds:
                    scans, poses = drive(seed, FRAMES, speed, turn)
                    keep, stamps = stamped_case(scans, truth, seed, args.gap)
                    for method in rows:
                        rows[method].append(run_case(model, scans, poses, keep, stamps, method, truth == "half"))
                for method, r in rows.items():
                    runs.append((case, speed, truth, method, r))
    print(f"seeds {lo}-{hi} ({len(seeds)}), model {args.model}, {args.gap} dropped, ambiguous sweep {AT} of {FRAMES}, "
          f"jitter ±{JITTER_US / 1e3:.0f} ms")
    print("| case | m/s | truth | method | k right | undecided | step err m (median / max) | yaw err ° (median / max) "
          "| speed err m/s (median / max) |")
    print("|---|---:|---|---|---:|---:|---:|---:|---:|")
    for case, speed, truth, method, r in runs:
        k, und, t, y, v = (np.array(c) for c in zip(*r))
        print(f"| {case} | {speed:g} | {truth} | {method} | {int(k.sum())}/{k.size} | {int(und.sum())} | "
              f"{np.median(t):.2f} / {t.max():.2f} | {np.median(y):.2f} / {y.max():.2f} | "
              f"{np.median(v):.2f} / {v.max():.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
