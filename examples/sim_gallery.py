"""Draw one simulated sweep per scenario: polar sweep | Cartesian image | static-label overlay.

    python examples/sim_gallery.py [-o sim_gallery.png] [--seed 7] [--sweep 12]

Cartesian images use the Oxford geometry (image up = +x forward, right = +y) at 0.2 m/px,
512 px (±51 m). In the overlay, green marks cells labelled static (power mainly from the
static world) and magenta everything else that rises above the noise floor (moving vehicles,
their ghosts and streaks, phase-noise arcs, the ego vehicle's own near-range clutter).
"""
from __future__ import annotations

import argparse

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="sim_gallery.png", help="PNG to write (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=7, help="world seed (default: %(default)s)")
    ap.add_argument("--sweep", type=int, default=12, help="which sweep of the drive to draw (default: %(default)s)")
    ap.add_argument("--resolution", type=float, default=0.2, help="Cartesian m/px (default: %(default)s)")
    ap.add_argument("--width", type=int, default=512, help="Cartesian width in px (default: %(default)s)")
    ap.add_argument("--scenarios", default="urban,heavy_traffic,open,highway",
                    help="comma-separated scenario names (default: %(default)s)")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radar_odom.polar import polar_to_cartesian, polar_to_cartesian_array
    from radar_odom.sim import Simulator

    names = [s for s in args.scenarios.split(",") if s]
    fig, axes = plt.subplots(len(names), 3, figsize=(18, 6 * len(names)), squeeze=False)
    half = args.width * args.resolution / 2
    extent = (-half, half, -half, half)  # (y left..right, x bottom..top)
    for row, name in zip(axes, names):
        sim = Simulator(args.seed, args.sweep + 1, name)
        fr = sim.frame(args.sweep)
        scan = fr.scan
        row[0].imshow(scan.power, aspect="auto", cmap="gray", vmin=0, vmax=1, interpolation="nearest",
                      extent=(0, scan.max_range_m, 360, 0))
        row[0].set(title=f"{name}: polar sweep (seed {args.seed}, sweep {args.sweep})",
                   xlabel="range (m)", ylabel="azimuth (deg)")
        cart = polar_to_cartesian(scan, args.resolution, args.width)
        row[1].imshow(cart, cmap="gray", vmin=0, vmax=min(1.0, float(np.percentile(cart, 99.9)) + 1e-3),
                      extent=extent)
        row[1].set(title=f"Cartesian {args.resolution} m/px", xlabel="y right (m)", ylabel="x forward (m)")
        lab = polar_to_cartesian_array((fr.static_label > 0).astype(np.float32), scan.azimuths_rad,
                                       scan.range_resolution_m, scan.range_offset_m, args.resolution, args.width)
        floor = np.percentile(cart, 60)
        bright = np.clip((cart - floor) / max(1e-3, float(np.percentile(cart, 99.5)) - floor), 0, 1)
        rgb = np.stack([bright * 0.25] * 3, axis=-1)
        static = lab > 0.5
        other = (~static) & (bright > 0.35)
        rgb[static] = np.stack([0.1 * bright[static], 0.4 + 0.6 * bright[static], 0.1 * bright[static]], -1)
        rgb[other] = np.stack([0.5 + 0.5 * bright[other], 0.1 * bright[other], 0.5 + 0.5 * bright[other]], -1)
        row[2].imshow(rgb, extent=extent)
        row[2].set(title="static label (green) / not static (magenta)", xlabel="y right (m)", ylabel="x forward (m)")
        speed = float(sim.drive.speed_at(np.mean(sim.drive_time_s(scan.timestamps_us))))
        row[1].text(-half + 2, -half + 2, f"ego {speed:.1f} m/s", color="yellow", fontsize=10)
    fig.tight_layout()
    fig.savefig(args.output, dpi=70)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
