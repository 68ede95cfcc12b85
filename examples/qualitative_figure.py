"""The paper's qualitative figure for a trained checkpoint, on a held-out simulated drive.

    python examples/qualitative_figure.py models/cart-0.8.pt [-o qualitative.png]
        [--scenario heavy_traffic] [--seed 5100] [--pair 40]

One row per checkpoint given: radar input | predicted mask | masked features |
correlation slice at the estimated yaw | covariance ellipse. In the input panel the cells
whose power is *not* labelled static by the simulator (moving vehicles, ghosts, streaks,
noise) are outlined in magenta, so one can check that the mask removes them and keeps walls.
The ellipse panel shows the soft-argmax estimate with its 1σ and 3σ x–y ellipses against the
ground truth. Needs the torch side, radar-odom-export (pip install -e ./export) and matplotlib.
"""
from __future__ import annotations

import argparse

import numpy as np


def ellipse_xy(mean_xy: np.ndarray, cov_xy: np.ndarray, k_sigma: float, n: int = 100) -> np.ndarray:
    """Points [n, 2] on the k-sigma ellipse of a 2-D Gaussian (x, y) in metres."""
    vals, vecs = np.linalg.eigh(cov_xy)
    t = np.linspace(0, 2 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    return mean_xy + k_sigma * (circle * np.sqrt(np.maximum(vals, 0))) @ vecs.T


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", help="checkpoints written by `radar-odom train` (.pt)")
    ap.add_argument("-o", "--output", default="qualitative.png", help="PNG to write (default: %(default)s)")
    ap.add_argument("--scenario", default="heavy_traffic", help="simulator scenario (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=5100, help="held-out world seed, >= 5000 (default: %(default)s)")
    ap.add_argument(
        "--pair", type=int, default=40, help="which consecutive pair (k, k+1) to draw (default: %(default)s)"
    )
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.data import DriveSpec, simulate_drive_arrays

    rows = []
    for path in args.checkpoints:
        model, meta = load_checkpoint(path)
        model.eval()
        p = model.profile
        drive = simulate_drive_arrays(p, DriveSpec(args.scenario, args.seed, args.pair + 2))
        prev = torch.from_numpy(drive.images[args.pair].astype(np.float32))[None]
        cur = torch.from_numpy(drive.images[args.pair + 1].astype(np.float32))[None]
        with torch.no_grad():
            mask = model.mask(cur)[0].numpy()
            feats = model.sweep_features(cur)[0].numpy()
            volume = model.correlation_volume(prev, cur)
            pose, cov = model.pose_from_volume(volume)
        rows.append(
            dict(
                path=path,
                meta=meta,
                profile=p,
                cur=cur[0].numpy(),
                mask=mask,
                feats=feats,
                label=drive.labels[args.pair + 1].astype(np.float32),
                volume=volume[0].numpy(),
                pose=pose[0].numpy().astype(np.float64),
                cov=cov[0].numpy().astype(np.float64),
                gt=drive.poses_rel[args.pair].astype(np.float64),
            )
        )

    fig, axes = plt.subplots(len(rows), 5, figsize=(25, 5.2 * len(rows)), squeeze=False)
    for ax, r in zip(axes, rows):
        p = r["profile"]
        half = p.width_px * p.resolution_m / 2
        extent = (-half, half, -half, half)  # Oxford image: up = +x forward, right = +y
        vmax = float(np.percentile(r["cur"], 99.8)) + 1e-3
        ax[0].imshow(r["cur"], cmap="gray", vmin=0, vmax=vmax, extent=extent)
        not_static = (r["label"] < 0.5) & (r["cur"] > np.percentile(r["cur"], 90))
        ax[0].contour(
            np.flipud(not_static.astype(float)), levels=[0.5], colors="magenta", linewidths=0.6, extent=extent
        )
        ax[0].set(
            title=f"{r['meta']['masking']} {p.name}: input (magenta: not static)",
            xlabel="y right (m)",
            ylabel="x forward (m)",
        )
        ax[1].imshow(r["mask"], cmap="viridis", vmin=0, vmax=1, extent=extent)
        ax[1].set(title=f"predicted mask (mean {r['mask'].mean():.2f})", xlabel="y right (m)")
        ax[2].imshow(r["feats"], cmap="gray", vmin=0, vmax=float(np.percentile(r["feats"], 99.8)) + 1e-6, extent=extent)
        ax[2].set(title="masked features M ⊙ Z", xlabel="y right (m)")

        # volume [K, N, N]: yaw k, then dx (rows, increasing), dy (cols) -- `candidate_poses`
        k = int(np.unravel_index(np.argmax(r["volume"]), r["volume"].shape)[0])
        win = (r["volume"].shape[-1] // 2) * p.resolution_m
        ax[3].imshow(r["volume"][k], cmap="magma", extent=(-win, win, -win, win), origin="lower")
        ax[3].plot(r["gt"][1], r["gt"][0], "c+", ms=14, mew=2, label="ground truth")
        ax[3].plot(r["pose"][1], r["pose"][0], "wx", ms=10, mew=2, label="estimate")
        yaw_deg = np.degrees(p.rotations_rad[k])
        ax[3].set(title=f"correlation slice, yaw {yaw_deg:+.1f}°", xlabel="dy (m)", ylabel="dx (m)")
        ax[3].legend(loc="lower right", fontsize=8)

        cov_xy = r["cov"][:2, :2][::-1, ::-1]  # plotted as (dy, dx)
        mean = np.array([r["pose"][1], r["pose"][0]])
        for ks, style in ((1, "-"), (3, "--")):
            e = ellipse_xy(mean, cov_xy, ks)
            ax[4].plot(e[:, 0], e[:, 1], "b" + style, label=f"{ks}σ")
        ax[4].plot(r["gt"][1], r["gt"][0], "c+", ms=14, mew=2, label="ground truth")
        ax[4].plot(*mean, "kx", ms=10, mew=2, label="estimate")
        span = 1.1 * max(
            np.abs(ellipse_xy(np.zeros(2), cov_xy, 3)).max(), np.abs(mean - r["gt"][[1, 0]]).max(), p.resolution_m
        )
        ax[4].set_xlim(mean[0] - span, mean[0] + span)
        ax[4].set_ylim(mean[1] - span, mean[1] + span)
        sd = np.sqrt(np.maximum(np.diag(r["cov"]), 0))
        ax[4].set(
            title=f"covariance: σx {sd[0]:.3f} m, σy {sd[1]:.3f} m, σyaw {np.degrees(sd[2]):.2f}°",
            xlabel="dy (m)",
            ylabel="dx (m)",
            aspect="equal",
        )
        ax[4].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{args.scenario}, world seed {args.seed}, sweeps {args.pair}→{args.pair + 1}")
    fig.tight_layout()
    fig.savefig(args.output, dpi=80)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
