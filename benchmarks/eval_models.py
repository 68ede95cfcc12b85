"""The README results table: checkpoints evaluated on held-out simulated drives.

    python benchmarks/eval_models.py raw-0.8.pt supervised-0.8.pt cart-0.8.pt \\
        raw-0.4.pt supervised-0.4.pt cart-0.4.pt -o benchmarks/results.json

Drives: one per scenario and seed in ``--seeds`` (policy: evaluation seeds are 5000 and up,
never used in training or calibration), ``--frames`` sweeps each. Metrics: KITTI translational
error (%) and rotational error (deg/m) over ground-truth path segments of ``--lengths`` metres
starting every ``--step`` frames, pooled over all segments of all drives (KITTI devkit);
mean d² of the covariance at the checkpoint's ``beta_cov`` (≈ 3 once calibrated); runtime per
pair = median of one streaming step in torch on this CPU (see `radar_odom_export.evaluate`).
The simulated drives are a few hundred metres long, so the KITTI lengths are (100, 200) m
rather than the devkit's 100…800 m.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path


def label_of(meta: dict) -> str:
    """Human name of a checkpoint's model: the baseline it is, or the learned masks."""
    objective = meta["train"].get("objective", "raw" if meta["masking"] == "raw" else "pose")
    name = {"raw": "raw scan", "cfar": "CFAR masks (no training)", "masks": "supervised masks",
            "pose": "learned masks"}[objective]
    p = meta["profile"]
    if objective == "raw" and p.input_norm == "none":
        name += ", unnormalised power (the paper's baseline)"
    if (p.unet_base_channels, p.unet_depth) != (8, 5) and objective != "raw":
        name += f" (U-Net {p.unet_base_channels}ch×{p.unet_depth})"
    return name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoints", nargs="+", help="checkpoints from `radar-odom train` (any profiles)")
    ap.add_argument("--seeds", default="5000", help="evaluation world seeds, >= 5000 (default: %(default)s)")
    ap.add_argument("--scenarios", default="urban,heavy_traffic,open,highway")
    ap.add_argument("--frames", type=int, default=240, help="sweeps per drive (default: %(default)s = 60 s)")
    ap.add_argument("--lengths", default="100,200", help="KITTI segment lengths in metres (default: %(default)s)")
    ap.add_argument("--step", type=int, default=4, help="frames between segment starts (default: %(default)s)")
    ap.add_argument("--pooling", choices=("segments", "sequences"), default="segments")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    ap.add_argument("--workers", type=int, default=2, help="processes simulating drives")
    ap.add_argument("--motion-prior", action="store_true",
                    help="also score each model's measurements fused by the runtime's motion prior (extra rows)")
    ap.add_argument("-o", "--output", default=None, help="write the full results as JSON here")
    ap.add_argument("--markdown", default=None, help="also write the tables to this markdown file")
    args = ap.parse_args(argv)

    import torch

    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.data import build_drives, check_seed_policy, parse_seeds, sim_specs
    from radar_odom_export.evaluate import evaluate_model, markdown_table, scenario_d2_table, scenario_table

    torch.set_num_threads(args.threads or os.cpu_count() or 1)
    seeds = parse_seeds(args.seeds)
    check_seed_policy(seeds, "eval")
    scenarios = [s for s in args.scenarios.split(",") if s]
    lengths = tuple(float(x) for x in args.lengths.split(","))
    specs = sim_specs(seeds, scenarios, args.frames)

    rows = []
    t0 = time.perf_counter()
    for path in args.checkpoints:
        model, meta = load_checkpoint(path)
        drives = build_drives(model.profile, specs, args.workers, with_labels=False, desc="evaluation drives")
        res = evaluate_model(model, drives, step=args.step, lengths=lengths, pooling=args.pooling,
                             progress_desc=f"{Path(path).name}")
        res.update(label=label_of(meta), checkpoint=str(path), calibrated="calibration" in meta,
                   path_m=[d["path_m"] for d in res["per_drive"]])
        estimates = res.pop("estimates")
        rows.append(res)
        if args.motion_prior:  # the same measurements through the runtime's motion prior
            fused = evaluate_model(model, drives, step=args.step, lengths=lengths, pooling=args.pooling,
                                   timing_repeats=0, motion_prior=True, estimates=estimates)
            fused.pop("estimates")
            fused.update(label=label_of(meta) + " + motion prior", checkpoint=str(path),
                         calibrated="calibration" in meta, path_m=res["path_m"])
            fused["runtime_ms_per_pair"] = res["runtime_ms_per_pair"]
            rows.append(fused)
        print(f"{Path(path).name}: {res['translation_percent']:.3f} %  {res['rotation_deg_per_m']:.4f} deg/m  "
              f"d² {res['mean_d2']:.3g}", file=sys.stderr)

    header = (f"Held-out simulated drives: scenarios {', '.join(scenarios)}; seeds {args.seeds}; "
              f"{args.frames} sweeps each ({min(r for x in rows for r in x['path_m']):.0f}–"
              f"{max(r for x in rows for r in x['path_m']):.0f} m). KITTI segments "
              f"{', '.join(f'{x:g}' for x in lengths)} m, step {args.step}, pooling {args.pooling}. "
              f"Runtime: torch {torch.__version__} CPU, {torch.get_num_threads()} threads, one streaming "
              f"step (batch 1) on {platform.processor() or platform.machine()}.")
    text = "\n\n".join([header, markdown_table(rows), "Translational error % per scenario:", scenario_table(rows),
                         "Mean d² per scenario:", scenario_d2_table(rows)])
    print(text)
    print(f"\n({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    if args.output:
        Path(args.output).write_text(json.dumps({"command": " ".join(sys.argv), "header": header, "rows": rows},
                                                indent=1, default=str))
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
