"""95 % covariance ellipses along one held-out open-road drive (issue 11: is the covariance honest?).

    python examples/covariance_ellipses.py                       # cart-0.4, open road, seed 5000
    python examples/covariance_ellipses.py --model cart-0.8 --scenario highway --seed 5001 -o hw.png

Runs a shipped model through `RadarOdometer` (default settings: motion prior on) over a simulated
drive and draws two panels:

* the 95 % ellipse of every n-th step's translation, each in its own frame (cross-track across,
  along-track up, equal scales), with the truth's offset from the estimate: a truth outside its
  ellipse is an overconfident step;
* each step's along-track and cross-track error against ±1.96 σ of the fused estimate and of the
  graph's own measurement.

It prints the share of steps whose error lies inside the 95 % region (χ² with 2 degrees of
freedom for the translation: 5.99; with 3 for the whole pose: 7.81) and the mean d².
"""
from __future__ import annotations

import argparse

import numpy as np

CHI2_2DOF_95 = 5.991
CHI2_3DOF_95 = 7.815


def ellipse_xy(cov_xy: np.ndarray, d2: float = CHI2_2DOF_95, n: int = 48) -> np.ndarray:
    """float[n, 2] points of the ellipse ``eᵀ Σ⁻¹ e = d2`` of a 2×2 covariance (about the origin)."""
    w, v = np.linalg.eigh(0.5 * (cov_xy + cov_xy.T))
    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1) * np.sqrt(np.maximum(w, 0.0) * d2)
    return circle @ v.T


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="cart-0.4", help="shipped model name or .onnx path (default: %(default)s)")
    ap.add_argument("--scenario", default="open", help="simulator scenario (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=5000, help="world seed, held out (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=240, help="sweeps (default: %(default)s)")
    ap.add_argument("--every", type=int, default=6, help="draw every n-th step's ellipse (default: %(default)s)")
    ap.add_argument("--spacing", type=float, default=1.5, help="metres between drawn ellipses (default: %(default)s)")
    ap.add_argument("--no-prior", action="store_true", help="motion prior off (the graph's measurement alone)")
    ap.add_argument("-o", "--output", default="covariance_ellipses.png")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radar_odom import RadarOdometer
    from radar_odom._progress import progress
    from radar_odom.evaluation.metrics import mahalanobis_sq
    from radar_odom.model_zoo import resolve_model
    from radar_odom.se2 import wrap_angle
    from radar_odom.sim import simulate_drive

    odo = RadarOdometer(resolve_model(args.model), motion_prior=not args.no_prior)
    est, cov, meas, meas_cov, gt = [], [], [], [], []
    frames = simulate_drive(args.seed, args.frames, scenario=args.scenario)
    for frame in progress(frames, total=args.frames, desc=f"{args.scenario}-{args.seed}", unit="sweep"):
        e = odo.step(frame.scan)
        if e is None:
            continue
        est.append(e.pose)
        cov.append(e.covariance)
        meas.append(e.measurement)
        meas_cov.append(e.measurement_covariance)
        gt.append(np.asarray(frame.pose_rel, dtype=np.float64).reshape(3))
    est, cov, meas, meas_cov, gt = map(np.asarray, (est, cov, meas, meas_cov, gt))

    err = gt - est  # truth − estimate, yaw wrapped to (−π, π]
    err[:, 2] = wrap_angle(err[:, 2])
    d2 = mahalanobis_sq(err, cov)
    d2_xy = np.einsum("pi,pij,pj->p", err[:, :2], np.linalg.inv(cov[:, :2, :2]), err[:, :2])
    inside_xy = float(np.mean(d2_xy <= CHI2_2DOF_95))
    inside = float(np.mean(d2 <= CHI2_3DOF_95))
    print(f"{args.model} on {args.scenario}-{args.seed}, {len(est)} steps, motion prior "
          f"{'off' if args.no_prior else 'on'}: mean d² {d2.mean():.2f} (3 if calibrated), "
          f"translation inside its 95 % ellipse {100 * inside_xy:.1f} %, pose inside its 95 % region "
          f"{100 * inside:.1f} % (95 % if calibrated)")

    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(14, 8.5), gridspec_kw={"height_ratios": [1, 1.3]})
    # every n-th step's 95 % ellipse in its own frame, side by side: cross-track error across,
    # along-track error up (equal scales: an open road's ellipse is tall and thin), the truth's
    # offset from the estimate as a dot; red where the truth lies outside
    spacing = args.spacing
    for j, k in enumerate(range(0, len(est), args.every)):
        ring = ellipse_xy(cov[k, :2, :2])[:, ::-1]  # columns (y, x): cross-track, along-track
        bad = d2_xy[k] > CHI2_2DOF_95
        ax.plot(j * spacing + ring[:, 0], ring[:, 1], color="C3" if bad else "C2", lw=0.8)
        ax.plot(j * spacing + err[k, 1], err[k, 0], "o", color="C3" if bad else "k", ms=2.5)
    ax.set_aspect("equal")
    ticks = np.arange(0, len(range(0, len(est), args.every)), 5)
    ax.set_xticks(ticks * spacing, [str(t * args.every) for t in ticks])
    ax.set_xlabel(f"step (ellipses {spacing:g} m apart; horizontal: cross-track error m)")
    ax.set_ylabel("along-track error m")
    ax.set_title(f"{args.model}, {args.scenario}-{args.seed}: 95 % ellipse of every {args.every}th step's "
                 f"translation (dot: truth − estimate; red: outside). {100 * inside_xy:.1f} % of all steps inside")
    t = np.arange(len(est))
    for i, (label, colour) in enumerate((("along-track (x)", "C0"), ("cross-track (y)", "C1"))):
        off = 0.0 if i == 0 else -1.0  # cross-track drawn 1 m below
        band = 1.96 * np.sqrt(cov[:, i, i])
        ax2.fill_between(t, off - band, off + band, color=colour, alpha=0.25, lw=0,
                         label=f"±1.96 σ, {label}, reported")
        mband = 1.96 * np.sqrt(meas_cov[:, i, i])
        ax2.plot(t, off + mband, color=colour, lw=0.5, ls=":", label=f"±1.96 σ, {label}, graph's measurement")
        ax2.plot(t, off - mband, color=colour, lw=0.5, ls=":")
        ax2.plot(t, err[:, i] + off, color=colour, lw=0.9, label=f"{label} error{'' if i == 0 else ' − 1 m'}")
    # the errors stay in view (the bands may not: an open road's along-track band is metres wide)
    ax2.set_ylim(min(-2.0, 1.1 * err[:, 0].min(), 1.1 * err[:, 1].min() - 1.0), max(1.5, 1.1 * err[:, 0].max()))
    ax2.set_xlabel("step")
    ax2.set_ylabel("m")
    ax2.set_title(f"errors against the 95 % bands; mean d² {d2.mean():.2f} (3 if calibrated)")
    ax2.legend(loc="lower left", fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(args.output, dpi=120)
    print(f"plot: {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
