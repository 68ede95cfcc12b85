"""How sharply the ``junctions`` scenario turns, from its ground truth, beside ``urban`` on the same seeds.

    python benchmarks/junction_turns.py                     # seeds 0-7, 100 sweeps, < 5 s
    python benchmarks/junction_turns.py --seeds 0-15 --scenarios junctions

Per seed: the largest heading change within 2 s (8 sweeps) and within 7 sweeps, how many distinct turns
reach >= 30 deg within 2 s, the total heading change, the largest yaw rate, and the speed range overall
and where the yaw rate exceeds 15 deg/s. Poses are the simulator's ground truth (each sweep's pose at its
mid time, what gt/radar_odometry.csv holds); nothing is rendered.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "sdk"))


def turn_stats(scenario: str, seed: int, frames: int) -> dict:
    from radar_odom.se2 import to_xyyaw
    from radar_odom.sim import SimConfig, Simulator

    sim = Simulator(seed, frames, scenario, SimConfig().with_sensor(num_bins=100))  # the drive, not the sweeps
    yaw = np.degrees(np.unwrap([to_xyyaw(sim.pose_mid(k))[2] for k in range(frames)]))
    t_mid = [float(np.mean(sim.drive_time_s(sim.timestamps_us(k)))) for k in range(frames)]
    speed = sim.drive.speed_at(t_mid)
    rate = np.abs(np.gradient(yaw)) * sim.config.sensor.sweep_hz
    in2s = np.abs(yaw[8:] - yaw[:-8])
    sharp = in2s >= 30.0
    turning = rate > 15.0
    return {
        "max in 2 s": in2s.max(), "max in 7": np.abs(yaw[7:] - yaw[:-7]).max(),
        "turns >= 30 in 2 s": int(sharp[0] + np.sum(sharp[1:] & ~sharp[:-1])),
        "total": np.abs(np.diff(yaw)).sum(), "max rate": rate.max(),
        "speed": (speed.min(), speed.max()),
        "turning speed": (speed[turning].min(), speed[turning].max()) if turning.any() else (np.nan, np.nan),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0-7", help="a range a-b or a comma-separated list")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--scenarios", default="junctions,urban")
    args = ap.parse_args(argv)
    a, _, b = args.seeds.partition("-")
    seeds = range(int(a), int(b) + 1) if b else [int(s) for s in args.seeds.split(",")]
    t0 = time.perf_counter()
    print("| scenario | seed | max turn in 2 s (deg) | in 7 sweeps | turns >= 30 deg in 2 s | total turn (deg) | "
          "max yaw rate (deg/s) | speed (m/s) | speed where > 15 deg/s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for scenario in args.scenarios.split(","):
        for seed in seeds:
            s = turn_stats(scenario, seed, args.frames)
            print(f"| {scenario} | {seed} | {s['max in 2 s']:.1f} | {s['max in 7']:.1f} | {s['turns >= 30 in 2 s']} | "
                  f"{s['total']:.0f} | {s['max rate']:.1f} | {s['speed'][0]:.1f}–{s['speed'][1]:.1f} | "
                  f"{s['turning speed'][0]:.1f}–{s['turning speed'][1]:.1f} |")
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
