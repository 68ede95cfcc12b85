"""Real vs simulated Navtech sweeps: the statistics of `radar_odom.sim.realism`, side by side.

    python benchmarks/realism.py                       # ../shared/data/real, 12 simulated sweeps each
    python benchmarks/realism.py --real DIR -o realism  # another copy of the real sweeps

For each installation we hold real sweeps of (Oxford Radar RobotCar, RADIATE) it simulates
urban drives with that installation's sensor preset (`radar_odom.sim.SENSOR_PRESETS`) and
prints one table: intensity quantiles, share of cells above fixed levels, mean power by range,
azimuthal variation and the speckle correlation lengths, with the simulated/real ratio and
whether it lies within ±30 %. Writes ``OUT/realism.md`` (the tables) and ``OUT/realism.png``
(a real and a simulated sweep of each installation on the same Cartesian rendering, and their
histograms).

The real sweeps are non-commercial data: they are read from where they lie, never copied.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_REAL = ROOT.parent / "shared" / "data" / "real"
SIM_SEEDS = (5900, 5901, 5902)  # held-out range (>= 5000): never used to fit anything


def real_scans(real_dir: Path) -> dict[str, list]:
    """{"oxford": [...], "radiate": [...]} RadarScans found under ``real_dir`` (either may be empty)."""
    from radar_odom import load_scan

    oxford = [load_scan(p) for p in sorted(real_dir.glob("oxford-*/radar/*.png"))]
    radiate = [load_scan(p, format="radiate") for p in sorted(real_dir.glob("radiate-*/Navtech_Polar/*.png"))]
    return {"oxford": oxford, "radiate": radiate}


def simulated_scans(preset: str, sweeps_per_seed: int = 4, seeds=SIM_SEEDS) -> list:
    """Urban sweeps of the given sensor preset (every other sweep, so they are not near-copies)."""
    from radar_odom.sim import get_sensor_preset, simulate_drive

    cfg = get_sensor_preset(preset)
    out = []
    for seed in seeds:
        frames = list(simulate_drive(seed, 2 * sweeps_per_seed, "urban", cfg))
        out += [f.scan for f in frames[1::2]]
    return out


def realism_rows(real: list, sim: list):
    from radar_odom.sim.realism import compare, mean_statistics

    return compare(mean_statistics(real), mean_statistics(sim))


def figure(pairs: dict[str, tuple], path: Path) -> None:
    """Cartesian renderings (0.25 m/px, 501 px, power 0–1 as is) and histograms, real vs simulated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radar_odom import polar_to_cartesian

    n = len(pairs)
    fig, axes = plt.subplots(n, 3, figsize=(13, 4.3 * n), squeeze=False)
    for row, (name, (real, sim)) in enumerate(pairs.items()):
        for col, (label, scan) in enumerate((("real", real), ("simulated", sim))):
            img = polar_to_cartesian(scan, 0.25, 501)
            axes[row, col].imshow(img, cmap="gray", vmin=0.0, vmax=1.0)
            axes[row, col].set_title(f"{name}: {label}")
            axes[row, col].axis("off")
        ax = axes[row, 2]
        bins = np.linspace(0, 1, 129)
        for label, scan, c in (("real", real, "C0"), ("simulated", sim, "C3")):
            ax.hist(scan.power.ravel(), bins=bins, histtype="step", density=True, log=True, color=c, label=label)
        ax.set_xlabel("power (load_scan, 0–1)")
        ax.set_ylabel("density (log)")
        ax.set_title(f"{name}: histogram of every cell")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--real", type=Path, default=DEFAULT_REAL, help="folder of real sweeps (shared/data/real layout)")
    ap.add_argument("--sweeps-per-seed", type=int, default=4, help="simulated sweeps per seed (3 seeds)")
    ap.add_argument("-o", "--out", type=Path, default=Path("realism"), help="output folder")
    args = ap.parse_args(argv)
    if not args.real.is_dir():
        print(f"no real sweeps at {args.real}: pass --real DIR (the shared/data/real folder)", file=sys.stderr)
        return 2
    from radar_odom.sim.realism import format_table

    real = real_scans(args.real)
    args.out.mkdir(parents=True, exist_ok=True)
    md, pairs = [], {}
    for name, scans in real.items():
        if not scans:
            continue
        sim = simulated_scans(name, args.sweeps_per_seed)
        rows = realism_rows(scans, sim)
        ok = sum(r[4] for r in rows)
        text = (f"### {name}: {len(scans)} real sweeps vs {len(sim)} simulated (urban, preset '{name}', "
                f"seeds {SIM_SEEDS[0]}–{SIM_SEEDS[-1]})\n\n" + format_table(rows)
                + f"\n\n{ok} of {len(rows)} statistics within ±30 %.\n")
        print(text)
        md.append(text)
        pairs[name] = (scans[0], sim[0])
    (args.out / "realism.md").write_text("\n".join(md))
    figure(pairs, args.out / "realism.png")
    print(f"wrote {args.out / 'realism.md'} and {args.out / 'realism.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
