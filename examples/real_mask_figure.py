"""What the mask learned, on a real sweep: input | learned mask | masked sweep, one row per checkpoint.

    python examples/real_mask_figure.py export/radar_odom_export/checkpoints/cart-0.4.pt cart-0.4-real.pt \\
        -o real-mask.png [--drive ../shared/data/real/radiate-2019-02-12-edinburgh] [--sweep 240]

The paper's qualitative figure on real data: the sweep is drawn on each checkpoint's own grid
as the runtime draws it (polar → Cartesian, near range blanked), the mask is the U-Net's output
and the masked sweep is what the correlation sees (mask ⊙ normalised sweep). The default sweep
lies in the last 80 sweeps of the shared drive, which ``radar-odom train --real`` never trains
on. Needs the torch side, radar-odom-export (pip install -e ./export) and matplotlib. Real sweeps
are read where they lie.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

DRIVE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", help="checkpoints (.pt) of learned-mask models")
    ap.add_argument("-o", "--output", default="real-mask.png", help="PNG to write (default: %(default)s)")
    ap.add_argument("--drive", type=Path, default=DRIVE, help="a real recording (default: the shared RADIATE drive)")
    ap.add_argument("--sweep", type=int, default=240, help="which sweep of the recording (default: %(default)s)")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from radar_odom.io import read_sequence
    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.data import scan_to_cartesian

    scan = read_sequence(args.drive)[args.sweep].scan
    fig, axes = plt.subplots(len(args.checkpoints), 3, figsize=(15, 5.2 * len(args.checkpoints)), squeeze=False)
    for ax, path in zip(axes, args.checkpoints):
        model, meta = load_checkpoint(path)
        model.eval()
        p = model.profile
        img = torch.from_numpy(scan_to_cartesian(scan, p).astype(np.float32))[None]
        with torch.no_grad():
            mask = model.mask(img)[0].numpy()
            feats = model.sweep_features(img)[0].numpy()
        half = p.width_px * p.resolution_m / 2
        extent = (-half, half, -half, half)  # up = +x forward, right = +y
        name = Path(path).name
        ax[0].imshow(img[0].numpy(), cmap="gray", vmin=0, vmax=float(np.percentile(img, 99.8)) + 1e-3, extent=extent)
        ax[0].set(title=f"{name}: real sweep {args.sweep} ({p.name} grid)", xlabel="y right (m)",
                  ylabel="x forward (m)")
        ax[1].imshow(mask, cmap="viridis", vmin=0, vmax=1, extent=extent)
        ax[1].set(title=f"learned mask (mean {mask.mean():.3f})", xlabel="y right (m)")
        ax[2].imshow(feats, cmap="gray", vmin=0, vmax=float(np.percentile(feats, 99.8)) + 1e-6, extent=extent)
        ax[2].set(title="masked sweep (what the correlation sees)", xlabel="y right (m)")
    fig.suptitle(f"{args.drive.name}, sweep {args.sweep}")
    fig.tight_layout()
    fig.savefig(args.output, dpi=70)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
