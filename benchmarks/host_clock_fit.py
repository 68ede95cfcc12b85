"""The ``radiate`` host clock (`radar_odom.sim.host_clock`) beside the real drive it was fitted to.

    python benchmarks/host_clock_fit.py                    # < 2 s
    python benchmarks/host_clock_fit.py --sweeps 40000 --seeds 1,2,3 --clocks radiate,clean

Left: the stamps of the shared RADIATE city drive (``../shared/data/real/radiate-2019-02-12-edinburgh``,
frames 201–480, read in place with the project's reader; never copied). Right: each clock applied to a
simulated sweep train of ``--sweeps`` sweeps 250 ms apart (one column per clock and seed). Every
statistic comes from `radar_odom.sim.host_clock.interval_stats` on the stamps in reception order: interval
quantiles (ms), the shares of intervals above 1.5 P, below 0.5 P and below 0, the stalls (a long interval
whose backlog drains within 300 intervals, in 2 or more) per 1000 sweeps and the length of their
catch-up runs (intervals until the stamps are back within 0.1 P of the line before the stall), the long
intervals drained by the next one (a backwards pair) and those never drained (dropped sweeps). P is the
median over 32-interval spans of their mean interval (the real drive: 249.87 ms; the time base's fit:
249.82 ms).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "sdk"))
DRIVE = ROOT.parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"
PERIOD_US = 250_000


def _runs(runs) -> str:
    if not runs:
        return "–"
    r = np.asarray(runs)
    return f"{int(np.percentile(r, 10))} / {int(np.median(r))} / {int(np.percentile(r, 90))} / {r.max()}"


def _quantile(q: int):
    return lambda s: f"{s[f'p{q}']:.1f}"


ROWS = (
    ("stamps", lambda s: f"{s['intervals'] + 1}"),
    ("P (ms)", lambda s: f"{s['period_ms']:.2f}"),
    *((f"p{q} interval (ms)", _quantile(q)) for q in (1, 10, 50, 90, 99)),
    ("share > 1.5 P", lambda s: f"{100 * s['long_share']:.2f} %"),
    ("share < 0.5 P", lambda s: f"{100 * s['short_share']:.2f} %"),
    ("share negative", lambda s: f"{100 * s['negative_share']:.2f} %"),
    ("share zero (duplicates)", lambda s: f"{100 * s['zero_share']:.2f} %"),
    ("stalls per 1000 sweeps", lambda s: f"{s['stalls_per_1000']:.1f}"),
    ("catch-up run p10 / median / p90 / max", lambda s: _runs(s["catch_up_runs"])),
    ("long then drained at once (per 1000)", lambda s: f"{1000 * s['single_late'] / (s['intervals'] + 1):.1f}"),
    ("long, never drained: drops (per 1000)", lambda s: f"{1000 * s['gaps'] / (s['intervals'] + 1):.1f}"),
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sweeps", type=int, default=40_000, help="length of the simulated sweep train")
    ap.add_argument("--seeds", default="1", help="comma-separated seeds of the clock's draws")
    ap.add_argument("--clocks", default="radiate", help="comma-separated presets (radar_odom.sim.host_clock.PRESETS)")
    ap.add_argument("--drive", type=Path, default=DRIVE, help="a RADIATE recording (Navtech_Polar.txt)")
    args = ap.parse_args(argv)

    from radar_odom.io.radiate import radiate_sweeps
    from radar_odom.sim.host_clock import host_clock, interval_stats

    t0 = time.perf_counter()
    columns = []
    if (args.drive / "Navtech_Polar.txt").is_file():
        _, stamps = radiate_sweeps(args.drive)
        columns.append((f"real: {args.drive.name}", interval_stats(stamps)))
    else:
        print(f"(no real drive at {args.drive}: simulated columns only)")
    true_us = np.arange(args.sweeps, dtype=np.int64) * PERIOD_US
    for name in args.clocks.split(","):
        clock = host_clock(name.strip())
        for seed in (int(s) for s in args.seeds.split(",")):
            clocked = clock.apply(true_us, seed=seed)
            columns.append((f"{clock.name}, {args.sweeps} sweeps, seed {seed}", interval_stats(clocked.stamps_us)))
    print("| statistic | " + " | ".join(name for name, _ in columns) + " |")
    print("|---|" + "---:|" * len(columns))
    for label, cell in ROWS:
        print(f"| {label} | " + " | ".join(cell(s) for _, s in columns) + " |")
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
