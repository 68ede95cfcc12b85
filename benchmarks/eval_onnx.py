"""Exported ONNX models on held-out simulated drives, as the runtime runs them.

Each model steps its stream form (the graph's own state, from an all-zero state) over drives
simulated for its own grid; the graph's output, and with ``--motion-prior`` also the same
measurements fused by the runtime's default motion prior (as `RadarOdometer` does). Metrics: KITTI translational
and rotational error and mean d², overall and per scenario (`radar_odom_export.evaluate`).

    python benchmarks/eval_onnx.py --seeds 5000 --frames 240 -o eval.json cart-0.4.onnx cart-0.2.onnx
    python benchmarks/eval_onnx.py --seeds 5000-5001 --motion-prior -o eval.json cart-0.4.onnx   # + the default prior
    python benchmarks/eval_onnx.py --seeds 2500-2503 --motion-prior --report-prior-scale 1 -o cal.json cart-0.4.onnx
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np


def evaluate_onnx(path, specs, threads: int, motion_prior: bool = False, prior_config=None) -> dict:
    from radar_odom.onnx_model import OnnxModel
    from radar_odom.se2 import turn_frame
    from radar_odom_export.data import build_drives
    from radar_odom_export.evaluate import evaluate_model

    model = OnnxModel(path, threads=threads)
    info = model.info
    drives = build_drives(info.profile, specs, 1, with_labels=False)
    sweep, state_name = info.inputs
    estimates, times = [], []
    for drive in drives:
        images = np.asarray(drive.images, dtype=np.float32)
        state = model.run({sweep: images[:1], state_name: np.zeros(info.state_shape, np.float32)})["state"]
        poses, covs = [], []
        for k in range(1, len(images)):
            t0 = time.perf_counter()
            out = model.run({sweep: np.ascontiguousarray(images[k][None]), state_name: state})
            times.append(time.perf_counter() - t0)
            state = out["state"]
            pose, cov = out["pose"].reshape(3).astype(np.float64), out["covariance"].reshape(3, 3).astype(np.float64)
            if info.mount_yaw_rad:  # an adapted model's matches, turned as the runtime turns them
                pose, cov = turn_frame(pose, cov, info.mount_yaw_rad)
            poses.append(pose)
            covs.append(cov)
        estimates.append((np.asarray(poses), np.asarray(covs)))
    model_info = SimpleNamespace(profile=info.profile, masking=info.masking)
    result = evaluate_model(model_info, drives, estimates=estimates, timing_repeats=0)
    out = {"profile": info.profile.name, "translation_percent": result["translation_percent"],
           "rotation_deg_per_m": result["rotation_deg_per_m"], "mean_d2": result["mean_d2"],
           "per_scenario": result["per_scenario"], "graph_median_ms": 1e3 * float(np.median(times)),
           "threads": threads}
    if motion_prior:  # the same measurements through the runtime's default motion prior
        fused = evaluate_model(model_info, drives, estimates=estimates, timing_repeats=0, motion_prior=True,
                               prior_config=prior_config)
        out["motion_prior"] = {k: fused[k] for k in ("translation_percent", "rotation_deg_per_m", "mean_d2",
                                                     "per_scenario")}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+", help="exported .onnx files (stream form)")
    ap.add_argument("--seeds", default="5000",
                    help="evaluation world seeds, >= 5000 (or 2000-2999: the validation and calibration drives)")
    ap.add_argument("--scenarios", default="urban,heavy_traffic,open,highway")
    ap.add_argument("--frames", type=int, default=240, help="sweeps per drive")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads")
    ap.add_argument("--motion-prior", action="store_true",
                    help="also score the measurements fused by the runtime's default motion prior")
    ap.add_argument("--report-prior-scale", type=float, default=None,
                    help="the prior's MotionPriorConfig.report_prior_scale (default: the runtime's; 1: the "
                         "filter's own covariance)")
    ap.add_argument("-o", "--output", required=True, help="JSON results")
    args = ap.parse_args(argv)

    from radar_odom_export.data import check_seed_policy, parse_seeds, sim_specs

    seeds = parse_seeds(args.seeds)
    check_seed_policy(seeds, "eval" if min(seeds) >= 5000 else "val")
    specs = sim_specs(seeds, args.scenarios.split(","), args.frames)
    results = {"command": " ".join(sys.argv)}
    prior_config = None
    if args.report_prior_scale is not None:
        from radar_odom.odometry.motion_prior import MotionPriorConfig

        prior_config = MotionPriorConfig(report_prior_scale=args.report_prior_scale)
    for path in args.models:
        r = evaluate_onnx(path, specs, args.threads, args.motion_prior, prior_config)
        results[Path(path).name] = r
        for label, row in [("", r)] + ([(" + motion prior", r["motion_prior"])] if args.motion_prior else []):
            scen = ", ".join(f"{s} {v['translation_percent']:.2f} (d² {v['mean_d2']:.2g})"
                             for s, v in row["per_scenario"].items())
            print(f"{Path(path).name}{label}: t {row['translation_percent']:.2f} % ({scen}), r "
                  f"{row['rotation_deg_per_m']:.4f} deg/m, mean d² {row['mean_d2']:.3g}", flush=True)
        print(f"{Path(path).name}: graph {r['graph_median_ms']:.1f} ms median", flush=True)
    Path(args.output).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
