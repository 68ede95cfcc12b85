"""Simulator speed at full CTS350-X resolution (400 azimuths × 3768 bins), per scenario.

    python benchmarks/bench_simulator.py [--frames 60] [--seed 0] [--scenarios urban,...] [--disk]

Times `Simulator.frame(k)` (ray casting, rendering, noise, labels, `RadarScan`) for every sweep
of a drive after building the world; ``--disk`` also times `write_drive` (adds PNG encoding).
Prints a markdown table: per-sweep wall-clock median and p90 in ms, sweeps/s (frames / total
time) and the median process CPU time per sweep (all threads: a number other processes on a
shared machine inflate less), with a machine line and the load average when it started.
"""
from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time

import cv2
import numpy as np


def machine_line() -> str:
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}, "
            f"OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads)")


def bench(name: str, seed: int, frames: int, disk: bool) -> dict:
    from radar_odom.sim import Simulator, write_drive

    t0 = time.perf_counter()
    sim = Simulator(seed, frames, name)
    setup = time.perf_counter() - t0
    times, cpu = [], []
    for k in range(frames):
        t, c = time.perf_counter(), time.process_time()
        sim.frame(k)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    ms = np.array(times) * 1e3
    row = {"scenario": name, "setup_s": setup, "median_ms": float(np.median(ms)),
           "p90_ms": float(np.percentile(ms, 90)), "sweeps_per_s": frames / (ms.sum() / 1e3),
           "cpu_ms": float(np.median(cpu) * 1e3)}
    if disk:
        with tempfile.TemporaryDirectory() as d:
            t = time.perf_counter()
            write_drive(d, seed, frames, name, progress=False)
            row["disk_sweeps_per_s"] = frames / (time.perf_counter() - t)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60, help="sweeps per scenario (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="world seed (default: %(default)s)")
    ap.add_argument("--scenarios", default="urban,heavy_traffic,open,highway")
    ap.add_argument("--disk", action="store_true", help="also time write_drive (PNG encoding included)")
    args = ap.parse_args(argv)

    load = os.getloadavg()[0]
    rows = [bench(n, args.seed, args.frames, args.disk) for n in args.scenarios.split(",") if n]
    print(f"machine: {machine_line()}; 1-min load average at start: {load:.2f}")
    print(f"simulator, full resolution 400 × 3768, {args.frames} sweeps per scenario, seed {args.seed}\n")
    head = "| scenario | world setup (s) | median ms/sweep | p90 ms/sweep | sweeps/s | CPU ms/sweep (all threads) |"
    sep = "|---|---:|---:|---:|---:|---:|"
    if args.disk:
        head += " sweeps/s written to disk |"
        sep += "---:|"
    print(head)
    print(sep)
    for r in rows:
        line = (f"| {r['scenario']} | {r['setup_s']:.2f} | {r['median_ms']:.1f} | {r['p90_ms']:.1f} "
                f"| {r['sweeps_per_s']:.1f} | {r['cpu_ms']:.1f} |")
        if args.disk:
            line += f" {r['disk_sweeps_per_s']:.1f} |"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
