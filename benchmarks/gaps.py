"""Crossing gaps: how far off is the pose over 1–8 dropped sweeps, on straights, in bends, in a
tightening turn and across speed changes?

    python benchmarks/gaps.py                                   # both shipped models; ≈ 3 min on 2 cores
    python benchmarks/gaps.py --models cart-0.4 --gaps 6 --cases bend,turn-in --seeds 10000-10003
    python benchmarks/gaps.py --markdown gaps-table.md
    python benchmarks/gaps.py --compare-plain --seeds 10040-10041   # also each crossing drawn as recorded
    python benchmarks/gaps.py --cause --models cart-0.4 --seeds 10001   # why a crossing fails; ≈ 1 min
    python benchmarks/gaps.py --readout --cases bend --gaps 6 --seeds 10020-10021   # crossing vs a match at the truth

Every model runs as `radar_odom.RadarOdometer` runs it (its defaults). Each crossing is a short
stream: ``--lead`` sweeps before the gap (so the period and the velocity are known), then the
sweep ``k + 1`` periods later (k = ``--gaps`` sweeps dropped) and one more. The crossing's
estimate (`Estimate.pose`, flagged ``"gap"``) is compared with the simulator's truth over the
same interval. Cases (``--cases``), every world simulated (`radar_odom.sim`) from ``--seeds``:

* ``straight``: a straight road at 10 m/s (`DriveConfig.constant_speed_mps`);
* ``bend``: a steady bend at 6 m/s turning 13° over the gap, whatever its length
  (`DriveConfig.constant_curvature_per_m`, as `benchmarks/yaw_precision.py` ``curve_scans``);
* ``turn-in``: a turn that tightens through the gap (curvature ramped over 30 m up to
  3°/sweep at 6.1 m/s), so the constant-velocity prediction is short of the turn;
* ``speed``: the simulator's own urban drives (no test hooks), gaps placed where the speed
  changes by at least 1 m/s over the gap (braking for, and accelerating out of, junctions).

``--readout`` prints instead, for every crossing of the chosen cases, gap lengths and seeds, the
odometer's crossing against one graph match centred on the *true* pose (the best any choice of
window centre or read-out of the agreeing matches could start from), then per model, case and
gap length the median / max of both: where the centred match is as far off as the crossing, the
error is the graph's reading over the long baseline, not where the window was put.

``--cause`` prints instead, for the ``turn-in`` drive's 6-sweep gaps, what one graph match reads with
the window centred on the *true* pose (the best any prediction could do) and on the true last
step scaled over the gap (a perfect constant-velocity prediction), against what the odometer's
crossing gives.

Per model, case and gap length: the crossing error (translation m, yaw °), median and max; how
many crossings were flagged ``gated`` (the match not taken); and the median d² of the crossing's
error under its reported covariance (3 dof: 3 is calibrated). Seeds must be fresh (>= 10000:
lower ones trained, calibrated or tuned something); they are printed, and ``--seeds`` reproduces
a run.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CASES = ("straight", "bend", "turn-in", "speed")
FRESH_SEED = 10000  # seeds below this trained, calibrated or tuned something
PERIOD_S = 0.25  # the simulator's sensor period (SimConfig().sensor.period_us)
BEND_DEG = 13.0  # yaw over the gap in the ``bend`` case


@dataclass(frozen=True)
class Crossing:
    """One gap to cross: the sweeps to step through, and the truth over the gap."""

    case: str
    seed: int
    gap: int  # sweeps dropped
    scans: tuple  # the stream: lead sweeps, the sweep after the gap, one more
    truth: np.ndarray  # float64[3] (x m, y m, yaw rad): the sweep after the gap in the last one before it


def parse_seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def _hooked_drive(seed: int, frames: int, speed_mps: float, rate_deg: float = 0.0, ramp_m: float | None = None):
    """(scans, absolute poses float64[N, 3, 3]) of a drive on the simulator's test hooks."""
    from radar_odom.se2 import chain_relative
    from radar_odom.sim.scenarios import steady_scenario
    from radar_odom.sim.simulator import simulate_drive

    extra = {} if ramp_m is None else {"curvature_ramp_m": ramp_m}
    frames_ = list(simulate_drive(seed, frames, steady_scenario("urban", speed_mps, rate_deg, **extra)))
    return [f.scan for f in frames_], chain_relative(np.array([f.pose_rel for f in frames_[1:]]))


def _natural_drive(seed: int, frames: int):
    from radar_odom.se2 import chain_relative
    from radar_odom.sim.simulator import simulate_drive

    frames_ = list(simulate_drive(seed, frames, "urban"))
    return [f.scan for f in frames_], chain_relative(np.array([f.pose_rel for f in frames_[1:]]))


def _crossing(case, seed, scans, poses, before: int, gap: int, lead: int) -> Crossing:
    from radar_odom.se2 import invert, to_xyyaw

    after = before + gap + 1
    idx = list(range(before - lead, before + 1)) + [after, after + 1]
    truth = to_xyyaw(invert(poses[before]) @ poses[after])
    return Crossing(case, seed, gap, tuple(scans[i] for i in idx), truth)


def crossings(case: str, seed: int, gaps: list[int], placements: int, lead: int) -> list[Crossing]:
    """The crossings of one case and seed, ``placements`` per gap length."""
    out = []
    if case == "straight":
        n = lead + 2 + max(gaps) + 2 + 2 * placements
        scans, poses = _hooked_drive(seed, n, 10.0)
        for k in gaps:
            out += [_crossing(case, seed, scans, poses, lead + 2 * p, k, lead) for p in range(placements)]
    elif case == "bend":
        for k in gaps:
            # the bend's ramp (8 m at 6 m/s: 5 sweeps) is over before the first placement
            n = lead + 6 + k + 2 + 2 * placements
            scans, poses = _hooked_drive(seed, n, 6.0, BEND_DEG / (k + 1))
            out += [_crossing(case, seed, scans, poses, lead + 6 + 2 * p, k, lead) for p in range(placements)]
    elif case == "turn-in":
        n = lead + 16 + max(gaps) + 2
        scans, poses = _hooked_drive(seed, n, 6.1, 3.0, ramp_m=30.0)
        starts = np.linspace(lead, lead + 12, placements).round().astype(int)
        for k in gaps:
            out += [_crossing(case, seed, scans, poses, int(b), k, lead) for b in starts]
    elif case == "speed":
        scans, poses = _natural_drive(seed, 240)
        speed = _speeds(poses)
        for k in gaps:
            cands = [b for b in range(lead, len(scans) - k - 3) if abs(speed[b + k + 1] - speed[b]) >= 1.0]
            for b in _spread(cands, placements):
                out.append(_crossing(case, seed, scans, poses, b, k, lead))
    else:
        raise SystemExit(f"unknown case {case!r}; cases: {', '.join(CASES)}")
    return out


def _speeds(poses) -> np.ndarray:
    """float64[N]: speed (m/s) over the interval ending at each sweep (the first repeats the second)."""
    from radar_odom.se2 import relative_from_absolute

    rel = relative_from_absolute(poses)
    v = np.hypot(rel[:, 0], rel[:, 1]) / PERIOD_S
    return np.concatenate([v[:1], v])


def _spread(items: list[int], count: int) -> list[int]:
    """Up to ``count`` of ``items``, spread evenly over them."""
    if len(items) <= count:
        return items
    return [items[int(i)] for i in np.linspace(0, len(items) - 1, count).round()]


def cross(model: str, c: Crossing, default: bool = True) -> dict:
    """Run the odometer (its defaults; ``default`` False: plain matching, `OdometerConfig.plain`) through one
    crossing; its error and flags."""
    from radar_odom import RadarOdometer
    from radar_odom.se2 import wrap_angle

    odo = RadarOdometer(model, config=None if default else "plain")
    est = [odo.step(s) for s in c.scans]
    gap_est = [e for e in est if e is not None and "gap" in e.flags]
    if len(gap_est) != 1:
        raise RuntimeError(f"seed {c.seed} {c.case} gap {c.gap}: {len(gap_est)} estimates flagged 'gap'")
    e = gap_est[0]
    err = np.asarray(e.pose, dtype=np.float64) - c.truth
    err[2] = float(wrap_angle(err[2]))
    d2 = float(err @ np.linalg.solve(e.covariance, err))
    return {"t": float(np.hypot(err[0], err[1])), "yaw": abs(math.degrees(err[2])), "d2": d2,
            "gated": "gated" in e.flags, "truth_yaw": math.degrees(c.truth[2]), "flags": sorted(e.flags)}


def single_match_error(model: str, ref_scan, new_scan, centre, truth) -> tuple[float, float]:
    """(translation m, yaw °) error of one graph match of ``new_scan`` against ``ref_scan`` with the
    window centred on ``centre`` (the new sweep drawn in that frame), composed back."""
    from radar_odom.odometry.gaps import compose_residual
    from radar_odom.odometry.sweep_input import SweepMotion, graph_input
    from radar_odom.onnx_model import OnnxModel
    from radar_odom.se2 import invert, se2, to_xyyaw, wrap_angle

    m = OnnxModel(model)
    i0, i1 = m.info.inputs[:2]
    zero = np.zeros(m.info.state_shape, dtype=np.float32)
    state = m.run({i0: graph_input(ref_scan, m.info), i1: zero})["state"]
    moved = graph_input(new_scan, m.info, SweepMotion(frame_pose=tuple(to_xyyaw(invert(se2(*centre))))))
    out = m.run({i0: moved, i1: state})
    pose, _ = compose_residual(np.asarray(out["pose"], dtype=np.float64).reshape(3), np.eye(3), centre)
    err = pose - truth
    return float(np.hypot(err[0], err[1])), abs(math.degrees(float(wrap_angle(err[2]))))


def cause(models: dict, seeds: list[int], lead: int) -> list[str]:
    """The ``--cause`` table: the turn-in drive's 6-sweep gaps, one match centred on the truth or on
    the true last step scaled over the gap (chord-scaled, as the crossing predicted before), against
    the odometer's crossing."""
    lines = ["| model | seed | sweeps before the gap | truth: x m, y m, yaw ° | one match centred on the truth: "
             "m, ° | one match centred on the true last step × 7: m, ° | the odometer's crossing: m, ° (flags) |",
             "|---|---:|---:|---|---|---|---|"]
    from radar_odom.se2 import relative_from_absolute

    for seed in seeds:
        scans, poses = _hooked_drive(seed, lead + 16 + 8, 6.1, 3.0, ramp_m=30.0)
        rel = relative_from_absolute(poses)
        for before in range(lead, lead + 12):
            c = _crossing(case="turn-in", seed=seed, scans=scans, poses=poses, before=before, gap=6, lead=lead)
            cv = rel[before - 1] * 7.0  # the true previous step scaled over 7 periods: a perfect CV prediction
            for name, path in models.items():
                t = single_match_error(path, scans[before], scans[before + 7], c.truth, c.truth)
                p = single_match_error(path, scans[before], scans[before + 7], cv, c.truth)
                r = cross(path, c)
                lines.append(f"| {name} | {seed} | {before} | {c.truth[0]:.2f}, {c.truth[1]:.2f}, "
                             f"{math.degrees(c.truth[2]):.1f} | {t[0]:.2f}, {t[1]:.2f} | {p[0]:.2f}, {p[1]:.2f} | "
                             f"{r['t']:.2f}, {r['yaw']:.2f} ({', '.join(r['flags'])}) |")
                print(lines[-1], flush=True)
    return lines


def readout(models: dict, todo: list) -> list[str]:
    """The ``--readout`` table: each crossing (translation m, yaw °, absolute errors; flags) against one
    match centred on its true pose, then the median / max of the errors per model, case and gap length."""
    lines = ["| model | case | gap | seed | truth yaw ° | the odometer's crossing: m, ° (flags) | "
             "one match centred on the truth: m, ° |", "|---|---|---:|---:|---:|---|---|"]
    rows: dict = {}
    for name, path in models.items():
        for c in todo:
            lead = len(c.scans) - 3  # the stream: lead sweeps, the sweep before the gap, the one after, one more
            r = cross(path, c)
            t = single_match_error(path, c.scans[lead], c.scans[lead + 1], c.truth, c.truth)
            rows.setdefault((name, c.case, c.gap), []).append((r, t))
            lines.append(f"| {name} | {c.case} | {c.gap} | {c.seed} | {r['truth_yaw']:.2f} | {r['t']:.2f}, "
                         f"{r['yaw']:.2f} ({', '.join(r['flags'])}) | {t[0]:.2f}, {t[1]:.2f} |")
            print(lines[-1], flush=True)
    lines += ["", "| model | case | gap (sweeps) | crossings | crossing m: median / max | crossing °: median / max "
              "| match at the truth m: median / max | match at the truth °: median / max |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    for (name, case, gap), rs in rows.items():
        a = np.array([[r["t"], r["yaw"], t[0], t[1]] for r, t in rs])
        med, top = np.median(a, axis=0), a.max(axis=0)
        cells = " | ".join(f"{med[i]:.2f} / {top[i]:.2f}" for i in range(4))
        lines.append(f"| {name} | {case} | {gap} | {len(rs)} | {cells} |")
    return lines


def table(results: dict) -> list[str]:
    lines = ["| model | case | gap (sweeps) | crossings | truth yaw (abs) ° | translation error m: median / max | "
             "yaw error °: median / max | gated | median d² |", "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for (model, case, gap), rows in results.items():
        t = np.array([r["t"] for r in rows])
        y = np.array([r["yaw"] for r in rows])
        ty = np.array([abs(r["truth_yaw"]) for r in rows])
        lines.append(f"| {model} | {case} | {gap} | {len(rows)} | {np.median(ty):.1f} | "
                     f"{np.median(t):.2f} / {t.max():.2f} | {np.median(y):.2f} / {y.max():.2f} | "
                     f"{sum(r['gated'] for r in rows)} | {np.median([r['d2'] for r in rows]):.1f} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", nargs="*", default=["cart-0.4", "cart-0.8"],
                    help="shipped model names or .onnx paths (default: %(default)s)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {CASES} (default: all)")
    ap.add_argument("--gaps", default="1,2,4,6,8", help="sweeps dropped (default: %(default)s)")
    ap.add_argument("--seeds", default="10000-10001", help=f"world seeds, >= {FRESH_SEED} (default: %(default)s)")
    ap.add_argument("--placements", type=int, default=3, help="gaps per case, seed and length (default: %(default)s)")
    ap.add_argument("--lead", type=int, default=5, help="sweeps before each gap (default: %(default)s)")
    ap.add_argument("--markdown", type=Path, default=None, help="write the table here too")
    ap.add_argument("--compare-plain", action="store_true",
                    help="each model also with plain matching (RadarOdometer(config='plain'), run --plain), "
                         "on the same crossings")
    ap.add_argument("--cause", action="store_true", help="the turn-in drive's single matches instead (see above)")
    ap.add_argument("--readout", action="store_true",
                    help="each crossing against one match centred on the truth (see above)")
    args = ap.parse_args(argv)

    from radar_odom import pretrained

    seeds = parse_seeds(args.seeds)
    if min(seeds) < FRESH_SEED:
        raise SystemExit(f"seeds must be >= {FRESH_SEED} (fresh); lower ones trained, calibrated or tuned something")
    gaps = [int(g) for g in args.gaps.split(",")]
    if min(gaps) < 1:
        raise SystemExit("--gaps: at least 1 sweep dropped (a crossing needs a gap)")
    models = {m: (m if m.endswith(".onnx") else pretrained(m)) for m in args.models}
    print(f"seeds {args.seeds}; cases {args.cases}; gaps {args.gaps}; placements {args.placements}", flush=True)
    t0 = time.time()
    if args.cause:
        lines = cause(models, seeds, args.lead)
        if args.markdown:
            args.markdown.write_text("\n".join(lines) + "\n")
        return 0
    todo = [c for case in args.cases.split(",") for s in seeds for c in crossings(case, s, gaps, args.placements,
                                                                                   args.lead)]
    print(f"{len(todo)} crossings simulated in {time.time() - t0:.0f} s", flush=True)
    if args.readout:
        lines = readout(models, todo)
        print("\n".join(lines[lines.index("") + 1:]))
        if args.markdown:
            args.markdown.write_text("\n".join(lines) + "\n")
        return 0
    results: dict = {}
    runs = [(name, path, True) for name, path in models.items()]
    if args.compare_plain:
        runs = [r for name, path in models.items() for r in ((f"{name}, plain matching", path, False),
                                                             (name, path, True))]
    for name, path, default in runs:
        for c in todo:
            results.setdefault((name, c.case, c.gap), []).append(cross(path, c, default))
    lines = table(results)
    print("\n".join(lines))
    print(f"\n({time.time() - t0:.0f} s)")
    if args.markdown:
        args.markdown.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
