"""Where do the fast search's large yaw errors come from: the coarse yaw stage, or the correlation?

    python benchmarks/yaw_outliers.py export/radar_odom_export/checkpoints/cart-0.4.pt --seeds 5002-5003

The fast search (`radar_odom_export.fast_search`) picks a yaw on low-resolution images, then
evaluates a band of 2b + 1 yaws around it (and yaw 0) at full resolution. A wrong band can hide
the true yaw. For every consecutive pair of the held-out drives whose yaw error exceeds
``--threshold`` degrees, this re-reads the pair with the same rotation and read-out over
*every* yaw candidate (a band as wide as the search) and sorts the step into

* ``coarse stage``: the full search is right (within half of ``--threshold``) and the band
  missed it;
* ``correlation``: the full search peaks wrong too; no choice of band would have helped.

It prints one row per step and the counts. Torch, the checkpoint's own profile (its
``rotation_identity`` included), ``--threads`` torch threads.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import replace


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoints", nargs="+", help="checkpoints (`radar-odom train` / `calibrate`)")
    ap.add_argument("--seeds", default="5000-5003", help="evaluation world seeds, >= 5000 (default: %(default)s)")
    ap.add_argument("--scenarios", default="urban,heavy_traffic,open,highway")
    ap.add_argument("--frames", type=int, default=240, help="sweeps per drive (default: %(default)s)")
    ap.add_argument("--threshold", type=float, default=1.5, help="yaw error in degrees that makes a step "
                    "an outlier (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    args = ap.parse_args(argv)

    import numpy as np
    import torch

    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.data import build_drives, check_seed_policy, parse_seeds, sim_specs
    from radar_odom_export.evaluate import pose_errors
    from radar_odom_export.fast_search import FastSequenceStep, FastStreamStep, default_settings

    torch.set_num_threads(args.threads or os.cpu_count() or 1)
    seeds = parse_seeds(args.seeds)
    check_seed_policy(seeds, "eval")
    limit = math.radians(args.threshold)
    for path in args.checkpoints:
        model, _ = load_checkpoint(path)
        model.eval()
        p = model.profile
        settings = default_settings(p)
        seq = FastSequenceStep(FastStreamStep(model, settings).eval())
        full = FastStreamStep(model, replace(settings, band_half_width=p.num_rotations // 2)).eval()
        drives = build_drives(p, sim_specs(seeds, args.scenarios.split(","), args.frames), 1, with_labels=False)
        print(f"\n## {os.path.basename(path)} ({p.name}, rotation_identity {p.rotation_identity}, "
              f"fast search {settings.label()}, seeds {args.seeds}, |yaw error| > {args.threshold}°)\n")
        print("| drive | step | true yaw ° | fast search ° | σ yaw ° | coarse pick ° | every yaw ° | cause |")
        print("|---|---:|---:|---:|---:|---:|---:|---|")
        counts = {"coarse stage": 0, "correlation": 0}
        pairs = 0
        for drive in drives:
            x = torch.from_numpy(np.asarray(drive.images, dtype=np.float32))
            with torch.no_grad():
                poses, covs = seq(x)
            poses, covs = poses.double().numpy(), covs.double().numpy()
            gt = np.asarray(drive.poses_rel, np.float64)
            err = pose_errors(gt, poses)
            pairs += len(err)
            for k in np.flatnonzero(np.abs(err[:, 2]) > limit):
                with torch.no_grad():
                    f = model.sweep_features(x[k : k + 2])
                    state = full.spectrum.to_natural(full.spectrum(f))
                    pick = int(seq.step.selector(state[:1], state[1:])[0])
                    every = full(x[k + 1 : k + 2], state[:1])[0][0].double().numpy()
                full_ok = abs(every[2] - gt[k, 2]) <= limit / 2
                cause = "coarse stage" if full_ok else "correlation"
                counts[cause] += 1
                print(f"| {drive.name} | {k} | {math.degrees(gt[k, 2]):.2f} | {math.degrees(poses[k, 2]):.2f} | "
                      f"{math.degrees(math.sqrt(covs[k, 2, 2])):.2f} | {math.degrees(p.rotations_rad[pick]):.2f} | "
                      f"{math.degrees(every[2]):.2f} | {cause} |", flush=True)
        total = sum(counts.values())
        print(f"\n{total} of {pairs} pairs have |yaw error| > {args.threshold}°: "
              + ", ".join(f"{v} {k}" for k, v in counts.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
