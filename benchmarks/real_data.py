"""Every real sweep we have, through exported models: the Oxford pair and the RADIATE run.

    python benchmarks/real_data.py                                   # the shipped cart-0.8 and cart-0.4
    python benchmarks/real_data.py raw-0.4.onnx cfar-0.4.onnx cart-0.4 --markdown real.md

MODEL is a shipped model's name (``radar_odom.pretrained_names()``) or an ``.onnx`` file. Each
model is run as the runtime runs it (`RadarOdometer`, polar→Cartesian in numpy, the graph in
onnxruntime), with the motion prior off so every figure is the graph's own measurement:

* Oxford (``oxford-2019-01-10-14-36-48``, one pair with ground truth): estimated forward
  motion and yaw against the ground-truth row; error in % of the forward motion and in degrees.
* RADIATE (``radiate-fog_6_0``, 18 consecutive sweeps, no usable ground truth): the forward
  motion of every consecutive pair (a car in town at ≈ 4 Hz: 1.8–3.5 m per sweep), and the
  three-sweep consistency ``|A→C − (A→B)∘(B→C)|`` (translation, metres) for every triple,
  where A→C is matched directly across the middle sweep.

The real sweeps are non-commercial data: read from where they lie, never copied.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_REAL = ROOT.parent / "shared" / "data" / "real"
OXFORD = "oxford-2019-01-10-14-36-48"
RADIATE = "radiate-fog_6_0"


def _odometer(model):
    from radar_odom import RadarOdometer

    try:
        return RadarOdometer(model, motion_prior=False)
    except TypeError:  # a runtime without the motion prior
        return RadarOdometer(model)


def match(model, a, b) -> np.ndarray:
    """float64[3]: pose of sweep ``b`` in sweep ``a``'s frame as the model measures it."""
    odo = _odometer(model)
    odo.step(a)
    est = odo.step(b)
    return np.asarray(getattr(est, "measurement", None) if getattr(est, "measurement", None) is not None else est.pose)


def oxford_pair(model, real: Path) -> dict:
    from radar_odom import read_sequence

    seq = read_sequence(real / OXFORD)
    gt = np.asarray(seq.gt_relative[0], dtype=np.float64)
    est = match(model, seq[0].scan, seq[1].scan)
    return {
        "gt_x_m": float(gt[0]), "est_x_m": float(est[0]), "est_y_m": float(est[1]),
        "x_error_percent": float(100 * abs(est[0] - gt[0]) / abs(gt[0])),
        "yaw_error_deg": float(np.degrees(abs(est[2] - gt[2]))),
    }


def radiate_run(model, real: Path) -> dict:
    from radar_odom import read_sequence
    from radar_odom.se2 import se2, to_xyyaw

    seq = read_sequence(real / RADIATE)
    scans = [f.scan for f in seq]
    pairs = [match(model, scans[k], scans[k + 1]) for k in range(len(scans) - 1)]
    consistency = []
    for k in range(len(scans) - 2):
        direct = match(model, scans[k], scans[k + 2])
        chained = to_xyyaw(se2(*pairs[k]) @ se2(*pairs[k + 1]))
        consistency.append(float(np.hypot(*(direct[:2] - chained[:2]))))
    fwd = np.array([p[0] for p in pairs])
    return {
        "forward_m": fwd.tolist(),
        "forward_min_m": float(fwd.min()), "forward_max_m": float(fwd.max()),
        "pairs_in_1.8_3.5_m": int(np.count_nonzero((fwd >= 1.8) & (fwd <= 3.5))), "pairs": len(fwd),
        "consistency_m": consistency,
        "consistency_max_m": float(max(consistency)), "consistency_median_m": float(np.median(consistency)),
    }


def resolve(name: str):
    import radar_odom

    return radar_odom.pretrained(name) if name in radar_odom.pretrained_names() else Path(name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("models", nargs="*", default=["cart-0.8", "cart-0.4"], metavar="MODEL")
    ap.add_argument("--real", type=Path, default=DEFAULT_REAL, help="folder of real sweeps (shared/data/real layout)")
    ap.add_argument("-o", "--json", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument("--markdown", type=Path, default=None, help="write the tables as markdown")
    args = ap.parse_args(argv)
    if not args.real.is_dir():
        print(f"no real sweeps at {args.real}: pass --real DIR (the shared/data/real folder)", file=sys.stderr)
        return 2
    results = {}
    for name in args.models:
        path = resolve(name)
        results[name if not name.endswith(".onnx") else Path(name).stem] = {
            "oxford": oxford_pair(path, args.real),
            "radiate": radiate_run(path, args.real),
        }
    lines = [
        "| model | Oxford x (gt {:.3f} m) | x error % | yaw error ° | RADIATE forward m (min–max) "
        "| pairs in 1.8–3.5 m | 3-sweep consistency m (median / max) |".format(
            next(iter(results.values()))["oxford"]["gt_x_m"]
        ),
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        o, d = r["oxford"], r["radiate"]
        lines.append(
            f"| {name} | {o['est_x_m']:.3f} | {o['x_error_percent']:.1f} | {o['yaw_error_deg']:.3f} "
            f"| {d['forward_min_m']:.2f}–{d['forward_max_m']:.2f} | {d['pairs_in_1.8_3.5_m']}/{d['pairs']} "
            f"| {d['consistency_median_m']:.3f} / {d['consistency_max_m']:.3f} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    if args.markdown:
        args.markdown.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
