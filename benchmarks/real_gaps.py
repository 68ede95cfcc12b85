"""Gaps cut into the shared real drive, crossed and compared with the GNSS/INS reference.

    python benchmarks/real_gaps.py                                  # cart-0.4, 2, 4 and 6 sweeps dropped; ≈ 4 min
    python benchmarks/real_gaps.py --models cart-0.4,cart-0.8 --gaps 6 --every 5 --markdown gaps.md

The simulated gaps (`benchmarks/gaps.py`) know the truth exactly; this is the same question on real sweeps.
The shared RADIATE city drive is read as `radar-odom run` reads it (its time base, `Sequence.time_base`),
and its GNSS/INS reference aligned once, as `benchmarks/real_drive.py` aligns it (the clock offset from the
default model's run over the whole drive). Only sweeps before ``--last`` (default 200) are used: the drive's
last 80 sweeps are the scorecard's held-out stretch and stay held out.

Gaps are cut in: from every ``--every``-th sweep ``b`` where the car moves (the reference's step over ``b`` ≥
``--min-step`` m), ``k`` sweeps (``--gaps``) after ``b`` are dropped. Each crossing is a short stream:
``--lead`` sweeps up to ``b``, then sweep ``b + k + 1`` and one more, run by `RadarOdometer` once with the
runtime's defaults and once with plain matching (``config="plain"``, `radar-odom run --plain`), on the very
same sweeps. The crossing's error is taken against the reference's relative pose of sweep ``b + k + 1`` in
sweep ``b`` (translation m, yaw °). The reference is not exact: over a 1.75 s crossing its own heading and
position carry errors of a few tenths of a degree and a decimetre or so, so small differences between the two
columns say little; large ones do.

Rows: per model, gap length and turn class (``straight``: the reference's yaw over the crossing under
``--turn-deg``; ``turning`` otherwise), the median, 90th percentile and maximum of both errors for the
crossing by the default and by plain matching, and how many crossings each kept the prediction (``gated``).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"
HELD_OUT_FROM = 200  # the scorecard's held-out stretch starts here (`benchmarks/scorecard.py`)


def crossing_error(model, scans, ref_poses, before: int, gap: int, lead: int, period_s: float,
                   default: bool) -> dict:
    """The odometer through one cut gap: its crossing's error against the reference, and its flags."""
    from radar_odom import RadarOdometer
    from radar_odom.odometry.gaps import GAP
    from radar_odom.odometry.motion_prior import GATED
    from radar_odom.se2 import invert, to_xyyaw, wrap_angle

    after = before + gap + 1
    odo = RadarOdometer(model, config=None if default else "plain")  # as radar-odom run: periods counted itself
    ests = [odo.step(scans[i]) for i in list(range(before - lead, before + 1)) + [after, after + 1]]
    crossing = ests[lead + 1]
    if crossing is None or GAP not in crossing.flags:
        raise RuntimeError(f"sweep {after}: the crossing after sweep {before} was not flagged a gap")
    truth = to_xyyaw(invert(ref_poses[before]) @ ref_poses[after])
    err = np.asarray(crossing.pose, dtype=np.float64) - truth
    return {"t": float(math.hypot(err[0], err[1])), "yaw": abs(math.degrees(float(wrap_angle(err[2])))),
            "truth_yaw": math.degrees(float(truth[2])), "gated": GATED in crossing.flags}


def placements(ref_poses, gap: int, lead: int, every: int, last: int, min_step_m: float) -> list[int]:
    """Sweeps ``b`` to cut a ``gap`` after: every ``every``-th from ``lead`` on, the crossing and the sweep
    after it before ``last``, the reference moving at least ``min_step_m`` over sweep ``b``."""
    from radar_odom.se2 import relative_from_absolute

    steps = np.hypot(*relative_from_absolute(ref_poses)[:, :2].T)  # steps[i]: sweep i → i + 1
    return [b for b in range(lead, last - gap - 2, every) if np.isfinite(steps[b - 1]) and steps[b - 1] >= min_step_m]


def table(rows: dict, turn_deg: float) -> list[str]:
    lines = [f"| model | gap (sweeps) | turn (reference yaw over the crossing, {turn_deg:g}° split) | crossings | "
             "default: m median / p90 / max | plain: m median / p90 / max | default: ° median / p90 / max "
             "| plain: ° median / p90 / max | gated (default / plain) |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|"]

    def stats(values):
        v = np.asarray(values)
        return f"{np.median(v):.2f} / {np.percentile(v, 90):.2f} / {v.max():.2f}"

    for (model, gap, turn), pairs in rows.items():
        d, p = [a for a, _ in pairs], [b for _, b in pairs]
        lines.append(f"| {model} | {gap} | {turn} | {len(pairs)} | {stats([r['t'] for r in d])} | "
                     f"{stats([r['t'] for r in p])} | {stats([r['yaw'] for r in d])} | {stats([r['yaw'] for r in p])} "
                     f"| {sum(r['gated'] for r in d)} / {sum(r['gated'] for r in p)} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--drive", type=Path, default=DRIVE,
                    help="RADIATE recording with GPS_IMU_Twist/ (default: %(default)s)")
    ap.add_argument("--models", default="cart-0.4", help="comma-separated model names or .onnx files "
                    "(default: %(default)s)")
    ap.add_argument("--gaps", default="2,4,6", help="sweeps dropped (default: %(default)s)")
    ap.add_argument("--every", type=int, default=10,
                    help="a gap cut after every this many sweeps (default: %(default)s)")
    ap.add_argument("--lead", type=int, default=5, help="sweeps before each gap (default: %(default)s)")
    ap.add_argument("--last", type=int, default=HELD_OUT_FROM,
                    help="use sweeps before this one only (default: %(default)s, the held-out stretch left out)")
    ap.add_argument("--min-step", type=float, default=1.0, help="the car moves at least this far (m) over the "
                    "sweep before the gap (default: %(default)s)")
    ap.add_argument("--turn-deg", type=float, default=3.0, help="|reference yaw over the crossing| from which a "
                    "crossing is 'turning' (default: %(default)s)")
    ap.add_argument("--markdown", type=Path, default=None, help="write the table here too")
    args = ap.parse_args(argv)
    if not (args.drive / "GPS_IMU_Twist").is_dir():
        print(f"{args.drive}: no RADIATE recording with GPS_IMU_Twist/ there (the shared real data?)", file=sys.stderr)
        return 2
    if args.last > HELD_OUT_FROM and args.drive == DRIVE:
        print(f"--last {args.last}: sweeps from {HELD_OUT_FROM} on are the held-out stretch; left out", file=sys.stderr)
        return 2
    from radar_odom import RadarOdometer, pretrained, pretrained_names
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence
    from radar_odom.model_zoo import default_model_name

    t0 = time.time()
    seq = read_sequence(args.drive)
    scans = [f.scan for f in seq]
    period_s = seq.time_base.period_s if seq.time_base is not None else None
    odo = RadarOdometer(pretrained(default_model_name()), sweep_period_s=period_s)
    for s in scans:
        odo.step(s)
    ref_poses, _, note = gnss_reference(seq.reference, seq.timestamps_us, odo.trajectory.poses,
                                        time_base=seq.time_base)
    print(note, flush=True)
    models = {m: (pretrained(m) if m in pretrained_names() else Path(m)) for m in args.models.split(",")}
    rows: dict = {}
    for gap in (int(g) for g in args.gaps.split(",")):
        where = placements(ref_poses, gap, args.lead, args.every, args.last, args.min_step)
        for name, path in models.items():
            for b in where:
                pair = [crossing_error(path, scans, ref_poses, b, gap, args.lead, period_s, dg) for dg in (True, False)]
                turn = "turning" if abs(pair[0]["truth_yaw"]) >= args.turn_deg else "straight"
                rows.setdefault((name, gap, turn), []).append(pair)
                print(f"{name} gap {gap} after sweep {b} (reference yaw {pair[0]['truth_yaw']:+.1f}°): default "
                      f"{pair[0]['t']:.2f} m {pair[0]['yaw']:.2f}°, plain {pair[1]['t']:.2f} m "
                      f"{pair[1]['yaw']:.2f}°", flush=True)
    lines = table(dict(sorted(rows.items())), args.turn_deg)
    print("\n".join(lines))
    print(f"\n({time.time() - t0:.0f} s)")
    if args.markdown:
        args.markdown.write_text(note + "\n\n" + "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
