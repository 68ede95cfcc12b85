"""The real-drive benchmark: every model on the shared RADIATE city drive against its GNSS/INS reference.

    python benchmarks/real_drive.py                       # shipped models, raw, CFAR, KISS-ICP; ≈ 5 min
    python benchmarks/real_drive.py --models cart-0.4 --no-deskew --no-kiss     # one row, ≈ 20 s
    python benchmarks/real_drive.py --markdown real-drive.md --plot real-drive.png
    python benchmarks/real_drive.py --stretch 200: --no-deskew     # the held-out last 80 sweeps only

Drive: ``../shared/data/real/radiate-2019-02-12-edinburgh`` (280 sweeps, ≈ 445 m through
Edinburgh, three pairs 0.5 s apart), time files as published. Every matcher runs as
``radar-odom run`` runs it: `RadarOdometer` with its defaults (motion prior on, gaps crossed),
once with de-skew off and once on. Rows:

* the shipped models (`radar_odom.pretrained_names`);
* raw-scan correlation and CFAR: the default model's graph (its profile as its ONNX metadata
  records it: grid, input normalisation, parabolic pose read-out) with the mask fixed to 1 (raw)
  or to a cell-averaging CFAR detection (training-free), exported here from
  `radar_odom_export.model.MaskedCorrelator` (needs the export extra; skipped without torch);
* KISS-ICP (``pip install ".[peer]"``) on the 40 strongest returns per azimuth above the sweep's
  99th power percentile, with its own de-skew as the "de-skew" row (`benchmarks/peer_kiss_icp.py`).

Reference: the GNSS/INS track aligned once, for every row alike: the INS heading turned onto the
GNSS track with its offset followed in time, the clock offset estimated from the default model's run (de-skew off),
both printed (`radar_odom.evaluation.reference.gnss_reference`). Score: KITTI translational (%) and rotational
(°/m) error, segments of 50–400 m (`radar_odom.evaluation.metrics.kitti_lengths_for`), a segment every 4
sweeps, pooled over segments; and per pair (`radar_odom.evaluation.metrics.step_biases`): the step scale
(Σ estimated / Σ reference step length over pairs moving ≥ 1 m), the direction of the estimated
translation against the reference's on straight pairs (median, + = to the sensor's +y, right),
the RMS yaw error per pair while moving and while standing still, the yaw slope over pairs turning
> 0.2° (1 = turns read in full) and, for the graph's own matches before the motion prior, its yaw
slope and the share of pairs read as exactly 0 yaw (the yaw pull); the covariance's fit, mean
and median d² of each step's reported covariance against the reference (χ²(3): 3 and 2.37) and
the share above χ²(3)'s 95 % point. The plot draws every trajectory (de-skew off) over the reference.
``--stretch A:B`` scores sweeps A..B−1 only (a fresh stream from A; the reference aligned on the
whole drive as above): ``200:`` is the last 80 sweeps (105 m), the stretch that
``radar-odom train --real`` holds out by default (``--real-holdout 80``).
The real sweeps are non-commercial data: read where they lie, never copied.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"
CHI2_3_95 = 7.815  # 95 % point of χ²(3): a calibrated covariance leaves 5 % of d² above it


def export_classical(masking: str, out_dir: Path, model_path) -> Path | None:
    """The graph of the ONNX model ``model_path`` (its profile as its metadata records it: grid,
    input normalisation, pose read-out) with a fixed ``masking`` ("raw" or "cfar") instead of
    the learned mask, fast search; None without torch."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return None
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.model import MaskedCorrelator
    from radar_odom_export.onnx_export import export_fast

    profile = OnnxModel(model_path, threads=1).info.profile
    path = out_dir / f"{masking}-{profile.resolution_m:g}.onnx"
    model = MaskedCorrelator(profile, masking=masking).eval()
    export_fast(model, path, verify=False, training_data=f"none ({masking} masking)")
    return path


def run_model(model, scans, deskew: bool, with_estimates: bool = False, centre_yaw: bool = False,
              config=None):
    """(absolute poses float64[N, 3, 3], seconds per sweep, gaps crossed) of one matcher, and
    with ``with_estimates`` its N − 1 estimates (`radar_odom.Estimate`) and its profile too. As `radar-odom run`
    runs it (the odometer counts the sensor's periods itself); ``config``: ``"plain"`` for plain matching."""
    from radar_odom import RadarOdometer

    options = {"deskew": deskew, "centre_yaw": centre_yaw} if config is None else {}
    odo = RadarOdometer(model, config=config, **options)
    t0 = time.perf_counter()
    ests = [e for e in (odo.step(s) for s in scans) if e is not None]
    gaps = sum("gap" in e.flags for e in ests)
    out = odo.trajectory.poses, (time.perf_counter() - t0) / len(scans), gaps
    return (*out, ests, odo.profile) if with_estimates else out


def covariance_fit(gt, est, estimates, profile) -> dict:
    """Mean and median d² of the estimates' covariances against the reference's relative poses
    (non-degenerate steps; χ²(3): mean 3, median 2.37) and the share above χ²(3)'s 95 % point."""
    from radar_odom.evaluation.metrics import covariance_jitter, mahalanobis_sq
    from radar_odom.se2 import relative_from_absolute

    gt_rel, est_rel = relative_from_absolute(gt), relative_from_absolute(est)
    good = np.all(np.isfinite(gt_rel), axis=1) & np.array([not e.degenerate for e in estimates])
    covs = np.stack([e.covariance for e in estimates])[good]
    d2 = mahalanobis_sq(gt_rel[good] - est_rel[good], covs,
                        covariance_jitter(profile.resolution_m, profile.rotation_step_rad))
    return {"mean": float(d2.mean()), "median": float(np.median(d2)), "above_95": float((d2 > CHI2_3_95).mean())}


def run_kiss(scans, deskew: bool) -> np.ndarray:
    """Absolute poses of KISS-ICP (the peer benchmark's configuration) over the sweeps."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from peer_kiss_icp import Options, scan_points
    from peer_kiss_icp import run_kiss as kiss_relative

    from radar_odom.se2 import chain_relative

    opt = Options()
    rel = kiss_relative([scan_points(s, opt) for s in scans], opt, deskew)
    return chain_relative(rel)


def score(gt, est, estimates=None) -> dict:
    """KITTI figures and per-pair biases of absolute poses ``est`` against ``gt``; with the run's
    `radar_odom.Estimate` list, the graph's own matches (``Estimate.measurement``, before the motion
    prior) give ``"graph"``: their yaw slope and exact-zero share (the yaw pull, `step_biases`)."""
    from radar_odom.evaluation.metrics import kitti_lengths_for, kitti_metrics, path_lengths_m, step_biases
    from radar_odom.se2 import relative_from_absolute

    lengths = kitti_lengths_for(path_lengths_m(gt)[-1])
    m = kitti_metrics(gt, est, step=4, lengths=lengths, pooling="segments")
    out = {"t": m["translation_percent"], "r": m["rotation_deg_per_m"], "segments": m["num_segments"],
           "lengths": lengths, "steps": step_biases(gt, est)}
    if estimates is not None:
        gt_rel = relative_from_absolute(gt)
        graph = np.array([e.measurement if e.measurement is not None else e.pose for e in estimates])
        ok = np.all(np.isfinite(gt_rel), axis=1) & np.array([not e.degenerate for e in estimates])
        out["graph"] = step_biases(gt_rel[ok], graph[ok])
    return out


def plot(path: Path, gt, rows: dict, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radar_odom.se2 import to_xyyaw

    fig, ax = plt.subplots(figsize=(8, 7))
    g = to_xyyaw(gt)
    ax.plot(g[:, 0], -g[:, 1], "k", lw=2.5, label="GNSS/INS reference (aligned)")
    for label, poses in rows.items():
        p = to_xyyaw(poses)
        ax.plot(p[:, 0], -p[:, 1], lw=1.3, label=label)
    ax.plot([0], [0], "o", color="tab:green")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, forward at start)")
    ax.set_ylabel("−y (m, left at start)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(f"{title}\nde-skew off; map view from above", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--drive", type=Path, default=DRIVE,
                    help="RADIATE recording with GPS_IMU_Twist/ (default: %(default)s)")
    ap.add_argument("--models", nargs="*", default=None,
                    help="model names or .onnx files (default: every shipped model)")
    ap.add_argument("--no-classical", action="store_true", help="leave out the raw and CFAR rows")
    ap.add_argument("--no-kiss", action="store_true", help="leave out KISS-ICP")
    ap.add_argument("--no-deskew", action="store_true", help="only the de-skew-off runs")
    ap.add_argument("--centre-yaw", action="store_true",
                    help="the model rows with RadarOdometer(centre_yaw=True) (each sweep drawn turned by the predicted "
                         "yaw); the reference's clock is still estimated from the default model's default run")
    ap.add_argument("--stretch", default=None, metavar="A:B",
                    help="score sweeps A..B-1 only (Python slice of the drive's sweeps, e.g. 200: for the "
                         "held-out last 80); default: the whole drive")
    ap.add_argument("--plain", action="store_true",
                    help="the model rows with plain matching (radar-odom run --plain: the stamps as recorded)")
    ap.add_argument("--markdown", type=Path, default=None, help="write the table here too")
    ap.add_argument("--plot", type=Path, default=None, help="write the trajectory plot here (PNG)")
    args = ap.parse_args(argv)
    if not (args.drive / "GPS_IMU_Twist").is_dir():
        print(f"{args.drive}: no RADIATE recording with GPS_IMU_Twist/ there (the shared real data?)", file=sys.stderr)
        return 2
    from radar_odom import pretrained, pretrained_names
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence
    from radar_odom.model_zoo import default_model_name

    seq = read_sequence(args.drive)
    scans = [f.scan for f in (read_sequence(args.drive, repair_stamps=False) if args.plain else seq)]
    names = args.models if args.models is not None else pretrained_names()
    default = default_model_name()
    models = {n: (pretrained(n) if n in pretrained_names() else Path(n)) for n in names}
    tmp = Path(tempfile.mkdtemp(prefix="real-drive-"))
    if not args.no_classical:
        for masking, label in (("raw", f"raw-scan correlation ({default} graph)"),
                               ("cfar", f"CFAR, no training ({default} graph)")):
            path = export_classical(masking, tmp, pretrained(default))
            if path is None:
                print(f"{label}: skipped (needs the export extra: torch)", file=sys.stderr)
            else:
                models[label] = path
    # the reference, once for every row: clock offset from the default model's own run
    # ... at the reader's own sweep times (its time base, `radar_odom.io.timebase`: one answer per run)
    ref_poses, _, _ = run_model(pretrained(default), [f.scan for f in seq], deskew=False)
    gt, info, note = gnss_reference(seq.reference, seq.timestamps_us, ref_poses, time_base=seq.time_base)
    if args.stretch:
        a, _, b = args.stretch.partition(":")
        part = slice(int(a) if a else None, int(b) if b else None)
        scans = scans[part]
        # the stretch's times are the reader's already (fitted on the whole drive): taken as they are
        gt, _, _ = gnss_reference(seq.reference, seq.timestamps_us[part], None, info["clock_offset_s"],
                                  repair_stamps=False)
        note += f"; scored on sweeps {part.start or 0}:{part.stop or len(seq)} only ({len(scans)} sweeps)"
    print(note)
    deskews = (False,) if args.no_deskew else (False, True)
    results, drawn = [], {}
    for label, model in models.items():
        for deskew in deskews:
            poses, s_per, gaps, ests, profile = run_model(model, scans, deskew, with_estimates=True,
                                                          centre_yaw=args.centre_yaw,
                                                          config="plain" if args.plain else None)
            sc = score(gt, poses, ests)
            sc["d2"] = covariance_fit(gt, poses, ests, profile)
            results.append((label, deskew, sc, f"{1e3 * s_per:.0f}", gaps))
            st = sc["steps"]
            print(f"{label:40s} de-skew {'on ' if deskew else 'off'}: {sc['t']:6.2f} %  {sc['r']:.4f} °/m  "
                  f"scale {st['scale']:.3f}  direction {st['direction_deg']:+.2f}°  yaw rms {st['yaw_rms_deg']:.2f}°  "
                  f"yaw slope {st['yaw_slope']:.3f} (graph {sc['graph']['yaw_slope']:.3f}, exact 0 "
                  f"{100 * sc['graph']['exact_zero_share']:.1f} %)  "
                  f"d² {sc['d2']['mean']:.3g} / {sc['d2']['median']:.3g} "
                  f"({1e3 * s_per:.0f} ms/sweep, {gaps} gaps crossed)", flush=True)
            if not deskew:
                drawn[label] = poses
    if not args.no_kiss:
        try:
            import kiss_icp  # noqa: F401
        except ImportError:
            print('KISS-ICP: skipped (pip install ".[peer]")', file=sys.stderr)
        else:
            for deskew in deskews:
                poses = run_kiss(scans, deskew)
                sc = score(gt, poses)
                results.append(("KISS-ICP, 40 strongest per azimuth above the 99th percentile", deskew, sc, "", ""))
                print(f"{'KISS-ICP':40s} de-skew {'on ' if deskew else 'off'}: {sc['t']:6.2f} %  {sc['r']:.4f} °/m",
                      flush=True)
                if not deskew:
                    drawn["KISS-ICP"] = poses
    lengths = results[0][2]["lengths"]
    lines = [
        f"{note}",
        "",
        f"KITTI-style on {len(scans)} sweeps ({lengths[0]}–{lengths[-1]} m segments every 4 sweeps, "
        f"{results[0][2]['segments']} segments):",
        "",
        "| matcher | de-skew | translation % | rotation °/m | step scale | direction ° | yaw RMS ° (moving / still) "
        "| yaw slope (graph alone) | exact-0 yaw, graph alone | d² mean / median (share > χ² 95 %) | ms per sweep "
        "| gaps crossed |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, deskew, sc, ms, gaps in results:
        st = sc["steps"]
        d2 = (f"{sc['d2']['mean']:.3g} / {sc['d2']['median']:.3g} ({100 * sc['d2']['above_95']:.0f} %)"
              if "d2" in sc else "")
        graph = sc.get("graph")
        slope = f"{st['yaw_slope']:.3f}" + (f" ({graph['yaw_slope']:.3f})" if graph else "")
        zeros = f"{100 * graph['exact_zero_share']:.1f} %" if graph else ""
        lines.append(f"| {label} | {'on' if deskew else 'off'} | {sc['t']:.2f} | {sc['r']:.4f} | {st['scale']:.3f} | "
                     f"{st['direction_deg']:+.2f} | {st['yaw_rms_deg']:.2f} / {st['yaw_rms_still_deg']:.2f} | {slope} "
                     f"| {zeros} | {d2} | {ms} | {gaps} |")
    table = "\n".join(lines)
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n")
    if args.plot:
        length = float(np.sum(np.linalg.norm(np.diff(gt[:, :2, 2], axis=0), axis=1)))
        plot(args.plot, gt, drawn, f"{args.drive.name}, {len(scans)} sweeps ({length:.0f} m)")
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
