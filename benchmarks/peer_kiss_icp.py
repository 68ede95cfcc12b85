"""Peer benchmark: KISS-ICP (a widely used LiDAR odometry) on radar sweeps turned into point clouds.

    pip install -e ".[peer]"                 # kiss-icp>=1.0
    python benchmarks/peer_kiss_icp.py                             # real sweeps, k = 40
    python benchmarks/peer_kiss_icp.py -k 40 --sim --markdown peer.md

Method. Each sweep (`radar_odom.RadarScan`) becomes a planar point cloud, the usual way of
feeding a scanning radar to a LiDAR pipeline ("KISS-ICP on the k strongest returns per
azimuth"):

* for every valid azimuth row, the candidate bins are those whose centre range
  ``range_offset_m + (b + 0.5) * range_resolution_m`` lies in ``(min_range, max_range)``;
* a bin is a return if its power exceeds the sweep's ``percentile``-th power percentile (99 by
  default: one threshold for the sweep, so rows of bare noise keep nothing), or with
  ``--percentile none`` the row's ``mean + sigmas * std`` (earlier releases: it kept every row's
  strongest noise, sensor-fixed, and read the shared RADIATE drive as standing still);
* of those, the ``k`` strongest are kept (fewer where fewer pass the threshold);
* each kept bin becomes the point ``(r cos a, r sin a, 0)`` in the sensor frame: azimuth
  ``a = 0`` along +x (forward), growing towards +y (right), i.e. the Oxford frame, so the poses
  KISS-ICP returns are Oxford-frame poses. Each point carries its azimuth's timestamp,
  normalised to [0, 1] over the sweep (used only when deskewing).

The clouds go to `kiss_icp.kiss_icp.KissICP` (point-to-point ICP against a voxel-hash local
map, adaptive correspondence threshold, constant-velocity initial guess) with the configuration
below. The relative pose of sweep k is ``inv(P[k-1]) @ P[k]`` of KISS-ICP's absolute poses,
read as Oxford ``(x, y, yaw)``: the pose of the later sweep in the earlier one's frame, x
forward, y right, yaw positive turning x towards y (`radar_odom.se2`).

Variants (one table row each):

* ``KISS-ICP (k=K)``: one run over the whole sequence, deskew off (its normal use: local map
  and constant-velocity motion model carried from sweep to sweep).
* ``KISS-ICP (k=K, deskew)``: the same with per-point timestamps and deskewing on. KISS-ICP
  1.x deskews every sweep to its *last* timestamp with the previous relative motion.
* ``KISS-ICP (k=K, pairwise)``: every pair matched by a fresh two-sweep run, the protocol of
  ``benchmarks/real_data.py`` (whose models run with their motion prior off).

With only two sweeps KISS-ICP has no motion model yet (initial guess = identity, deskew has
nothing to apply, threshold at its initial value): the Oxford pair and every direct A→C match
of the consistency figure are such two-sweep runs, so the three rows share those numbers.
That is how KISS-ICP works, not a fault of the benchmark.

Data (same figures and layout as ``benchmarks/real_data.py``):

* Oxford ``oxford-2019-01-10-14-36-48``: one pair with ground truth; estimated forward motion,
  its error in % and the yaw error in degrees.
* RADIATE ``radiate-fog_6_0``: 18 sweeps, no usable ground truth; forward motion of each
  consecutive pair (a car in town at ≈ 4 Hz: 1.8–3.5 m), and the three-sweep consistency
  ``|A→C − (A→B)∘(B→C)|`` (translation, metres) where A→C comes from a fresh KISS-ICP run on
  just A then C.
* ``--sim``: simulated drives (`radar_odom.sim.simulate_drive`, held-out seed ≥ 5000), per
  pair forward error and KITTI metrics (`radar_odom.kitti_metrics`, step 4, segments of
  100/200 m as in ``benchmarks/eval_models.py``) on the chained relative poses.

Parameters, as radar users configure KISS-ICP: ``-k`` returns per azimuth (40) above the
sweep's ``--percentile`` power percentile (99; ``none``: above each row's mean + ``--sigmas``
standard deviations, the configuration of earlier releases, which kept the sensor-fixed noise
of every row and read the shared RADIATE drive as standing still: step scale 0.006),
``--min-range``/``--max-range`` (2 m / 100 m, also KISS-ICP's ``data.min_range``/``max_range``),
``--voxel`` KISS-ICP ``mapping.voxel_size`` (0.5 m), ``--threads`` for KISS-ICP's registration
(1: this is a shared machine).

The real sweeps are non-commercial data: read from where they lie, never copied.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_REAL = ROOT.parent / "shared" / "data" / "real"
OXFORD = "oxford-2019-01-10-14-36-48"
RADIATE = "radiate-fog_6_0"
SIM_SEED = 5000  # evaluation seeds are 5000 and up (never used in training)
SIM_SCENARIOS = ("urban", "open")
SIM_FRAMES = 120
SIM_LENGTHS_M = (100, 200)


@dataclass(frozen=True)
class Options:
    """How sweeps become clouds and how KISS-ICP is configured (see the module docstring)."""

    k: int = 40
    sigmas: float = 1.0
    percentile: float | None = 99.0  # returns above the sweep's this power percentile (None: mean + sigmas·std per row)
    min_range_m: float = 2.0
    max_range_m: float = 100.0
    voxel_m: float = 0.5
    threads: int = 1


@dataclass(frozen=True)
class Variant:
    """One way of running KISS-ICP over a sequence (a table row)."""

    suffix: str
    deskew: bool = False
    pairwise: bool = False

    def label(self, k: int) -> str:
        return f"KISS-ICP (k={k}{', ' + self.suffix if self.suffix else ''})"


VARIANTS = (Variant(""), Variant("deskew", deskew=True), Variant("pairwise", pairwise=True))


def scan_points(scan, opt: Options) -> tuple[np.ndarray, np.ndarray]:
    """float64[N, 3] Oxford-frame points and float64[N] times in [0, 1] from one sweep.

    The ``opt.k`` strongest bins per valid azimuth whose power exceeds the sweep's
    ``opt.percentile``-th power percentile (or, with ``percentile=None``, that row's
    ``mean + opt.sigmas * std``) over the bins in ``(min_range_m, max_range_m)``.
    """
    ranges = scan.range_offset_m + (np.arange(scan.num_bins) + 0.5) * scan.range_resolution_m
    window = (ranges > opt.min_range_m) & (ranges < opt.max_range_m)
    ranges = ranges[window]
    rows = np.flatnonzero(scan.valid)
    power = scan.power[rows][:, window].astype(np.float64)
    if opt.percentile is not None:  # one threshold for the sweep: rows of bare noise keep nothing
        thresh = np.percentile(power, opt.percentile)
    else:
        thresh = power.mean(axis=1, keepdims=True) + opt.sigmas * power.std(axis=1, keepdims=True)
    score = np.where(power > thresh, power, -np.inf)
    k = min(opt.k, score.shape[1])
    top = np.argpartition(-score, k - 1, axis=1)[:, :k]
    keep = np.isfinite(np.take_along_axis(score, top, axis=1))
    row_idx = np.broadcast_to(rows[:, None], top.shape)[keep]
    r, az = ranges[top[keep]], scan.azimuths_rad[row_idx].astype(np.float64)
    points = np.stack([r * np.cos(az), r * np.sin(az), np.zeros_like(r)], axis=1)
    ts = scan.timestamps_us.astype(np.float64)
    span = ts[rows[-1]] - ts[rows[0]]
    times = (ts[row_idx] - ts[rows[0]]) / span if span > 0 else np.zeros(len(r))
    return points, times


def kiss(opt: Options, deskew: bool):
    """A fresh `KissICP` configured for planar radar clouds."""
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    config = load_config(None)
    config.data.max_range = opt.max_range_m
    config.data.min_range = opt.min_range_m
    config.data.deskew = deskew
    config.mapping.voxel_size = opt.voxel_m
    config.registration.max_num_threads = opt.threads
    return KissICP(config)


def to_xyyaw(t4: np.ndarray) -> np.ndarray:
    """Oxford (x, y, yaw) of a 4×4 rigid transform (its planar part)."""
    return np.array([t4[0, 3], t4[1, 3], np.arctan2(t4[1, 0], t4[0, 0])])


def run_kiss(clouds, opt: Options, deskew: bool = False) -> np.ndarray:
    """float64[N-1, 3]: relative Oxford poses of consecutive clouds from one KISS-ICP run."""
    odo = kiss(opt, deskew)
    poses = []
    for points, times in clouds:
        odo.register_frame(points, times)
        poses.append(odo.last_pose.copy())
    return np.array([to_xyyaw(np.linalg.inv(a) @ b) for a, b in zip(poses[:-1], poses[1:])]).reshape(-1, 3)


def relative_poses(clouds, opt: Options, variant: Variant) -> np.ndarray:
    """float64[N-1, 3] relative poses of consecutive clouds under one variant."""
    if variant.pairwise:
        return np.concatenate([run_kiss(clouds[i:i + 2], opt, variant.deskew) for i in range(len(clouds) - 1)])
    return run_kiss(clouds, opt, variant.deskew)


def oxford_pair(real: Path, opt: Options, variant: Variant) -> dict:
    from radar_odom import read_sequence
    from radar_odom.se2 import wrap_angle

    seq = read_sequence(real / OXFORD)
    gt = np.asarray(seq.gt_relative[0], dtype=np.float64)
    clouds = [scan_points(seq[i].scan, opt) for i in (0, 1)]
    est = relative_poses(clouds, opt, variant)[0]
    return {
        "gt_x_m": float(gt[0]), "est_x_m": float(est[0]), "est_y_m": float(est[1]),
        "est_yaw_deg": float(np.degrees(est[2])), "points": [len(c[0]) for c in clouds],
        "x_error_percent": float(100 * abs(est[0] - gt[0]) / abs(gt[0])),
        "yaw_error_deg": float(np.degrees(abs(wrap_angle(est[2] - gt[2])))),
    }


def radiate_run(real: Path, opt: Options, variant: Variant) -> dict:
    from radar_odom import read_sequence
    from radar_odom.se2 import se2
    from radar_odom.se2 import to_xyyaw as se2_xyyaw

    seq = read_sequence(real / RADIATE)
    clouds = [scan_points(f.scan, opt) for f in seq]
    pairs = relative_poses(clouds, opt, variant)
    consistency, direct_fwd = [], []
    for i in range(len(clouds) - 2):
        direct = run_kiss([clouds[i], clouds[i + 2]], opt, variant.deskew)[0]
        chained = se2_xyyaw(se2(*pairs[i]) @ se2(*pairs[i + 1]))
        consistency.append(float(np.hypot(*(direct[:2] - chained[:2]))))
        direct_fwd.append(float(direct[0]))
    fwd = pairs[:, 0]
    return {
        "forward_m": fwd.tolist(), "points_median": int(np.median([len(c[0]) for c in clouds])),
        "forward_min_m": float(fwd.min()), "forward_max_m": float(fwd.max()),
        "pairs_in_1.8_3.5_m": int(np.count_nonzero((fwd >= 1.8) & (fwd <= 3.5))), "pairs": len(fwd),
        "consistency_m": consistency, "direct_a_to_c_forward_m": direct_fwd,
        "consistency_max_m": float(max(consistency)), "consistency_median_m": float(np.median(consistency)),
    }


def sim_drive(scenario: str, seed: int, frames: int, opt: Options, variants) -> dict:
    """Per-variant figures on one simulated drive: per-pair forward error and KITTI metrics."""
    from radar_odom import kitti_metrics
    from radar_odom.se2 import chain_relative, wrap_angle
    from radar_odom.sim import simulate_drive

    clouds, gt = [], []
    for f in simulate_drive(seed, frames, scenario):
        clouds.append(scan_points(f.scan, opt))
        if f.pose_rel is not None:
            gt.append(np.asarray(f.pose_rel, dtype=np.float64))
    gt = np.array(gt)
    gt_abs = chain_relative(gt)
    out = {}
    for v in variants:
        est = relative_poses(clouds, opt, v)
        fwd_err = 100 * np.abs(est[:, 0] - gt[:, 0]) / np.maximum(np.abs(gt[:, 0]), 1e-3)
        row = {"forward_error_percent_median": float(np.median(fwd_err)),
               "forward_error_percent_p90": float(np.percentile(fwd_err, 90)),
               "yaw_error_deg_median": float(np.degrees(np.median(np.abs(wrap_angle(est[:, 2] - gt[:, 2]))))),
               "path_m": float(np.abs(gt[:, 0]).sum())}
        try:
            m = kitti_metrics(gt_abs, chain_relative(est), step=4, lengths=SIM_LENGTHS_M)
            row.update(translation_percent=m["translation_percent"], rotation_deg_per_m=m["rotation_deg_per_m"])
        except ValueError:  # drive shorter than the shortest segment
            row.update(translation_percent=float("nan"), rotation_deg_per_m=float("nan"))
        out[v.label(opt.k)] = row
    return out


def real_table(results: dict) -> str:
    first = next(iter(results.values()))["oxford"]
    lines = ["| model | Oxford x (gt {:.3f} m) | x error % | yaw error ° | RADIATE forward m (min–max) "
             "| pairs in 1.8–3.5 m | 3-sweep consistency m (median / max) |".format(first["gt_x_m"]),
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, r in results.items():
        o, d = r["oxford"], r["radiate"]
        lines.append(f"| {name} | {o['est_x_m']:.3f} | {o['x_error_percent']:.1f} | {o['yaw_error_deg']:.3f} "
                     f"| {d['forward_min_m']:.2f}–{d['forward_max_m']:.2f} | {d['pairs_in_1.8_3.5_m']}/{d['pairs']} "
                     f"| {d['consistency_median_m']:.3f} / {d['consistency_max_m']:.3f} |")
    return "\n".join(lines)


def sim_table(sim: dict) -> str:
    lines = ["| model | scenario | path m | forward error % (median / p90) | yaw error ° (median) "
             "| KITTI trans. err % | rot. err deg/m |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for scenario, rows in sim.items():
        for name, r in rows.items():
            lines.append(f"| {name} | {scenario} | {r['path_m']:.0f} | {r['forward_error_percent_median']:.1f} / "
                         f"{r['forward_error_percent_p90']:.1f} | {r['yaw_error_deg_median']:.3f} "
                         f"| {r['translation_percent']:.2f} | {r['rotation_deg_per_m']:.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--real", type=Path, default=DEFAULT_REAL, help="folder of real sweeps (shared/data/real layout)")
    ap.add_argument("-k", type=int, default=Options.k, help="strongest returns kept per azimuth")
    ap.add_argument("--sigmas", type=float, default=Options.sigmas,
                    help="threshold with --percentile none: row mean + SIGMAS × row std")
    ap.add_argument("--percentile", default=str(Options.percentile),
                    help="threshold: the sweep's power percentile (default: %(default)s); 'none': per row, --sigmas")
    ap.add_argument("--min-range", type=float, default=Options.min_range_m, help="metres")
    ap.add_argument("--max-range", type=float, default=Options.max_range_m, help="metres")
    ap.add_argument("--voxel", type=float, default=Options.voxel_m, help="KISS-ICP mapping.voxel_size, metres")
    ap.add_argument("--threads", type=int, default=Options.threads, help="KISS-ICP threads (0: all cores)")
    ap.add_argument("--sim", action="store_true",
                    help=f"also simulated drives ({', '.join(SIM_SCENARIOS)}, {SIM_FRAMES} sweeps, seed {SIM_SEED})")
    ap.add_argument("--sim-frames", type=int, default=SIM_FRAMES)
    ap.add_argument("-o", "--json", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument("--markdown", type=Path, default=None, help="write the tables as markdown")
    args = ap.parse_args(argv)
    if args.k < 1:
        ap.error("-k must be at least 1")
    if not args.real.is_dir():
        print(f"no real sweeps at {args.real}: pass --real DIR (the shared/data/real folder)", file=sys.stderr)
        return 2
    try:
        from importlib.metadata import version

        kiss_version = version("kiss-icp")
    except Exception:
        print('kiss-icp is not installed: pip install -e ".[peer]"  (or pip install kiss-icp)', file=sys.stderr)
        return 2
    percentile = None if str(args.percentile).lower() == "none" else float(args.percentile)
    opt = Options(args.k, args.sigmas, percentile, args.min_range, args.max_range, args.voxel, args.threads)
    t0 = time.perf_counter()
    results = {v.label(opt.k): {"oxford": oxford_pair(args.real, opt, v), "radiate": radiate_run(args.real, opt, v)}
               for v in VARIANTS}
    above = (f"the sweep's {opt.percentile:g}th power percentile" if opt.percentile is not None
             else f"row mean + {opt.sigmas:g} std")
    header = (f"KISS-ICP {kiss_version} on radar point clouds: {opt.k} strongest returns per azimuth above "
              f"{above}, {opt.min_range_m:g}–{opt.max_range_m:g} m; voxel {opt.voxel_m:g} m. "
              "Two-sweep runs (Oxford pair, direct A→C) have no motion model yet, so all rows share them.")
    tables = [header, real_table(results)]
    out = {"kiss_icp_version": kiss_version, "options": opt.__dict__, "real": results}
    if args.sim:
        sim = {s: sim_drive(s, SIM_SEED, args.sim_frames, opt, VARIANTS) for s in SIM_SCENARIOS}
        out["sim"] = sim
        tables += [f"Simulated drives (seed {SIM_SEED}, {args.sim_frames} sweeps each; KITTI step 4, "
                   f"segments {'/'.join(map(str, SIM_LENGTHS_M))} m):", sim_table(sim)]
    out["runtime_s"] = time.perf_counter() - t0
    text = "\n\n".join(tables)
    print(text)
    print(f"\n({out['runtime_s']:.0f} s)", file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    if args.markdown:
        args.markdown.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
