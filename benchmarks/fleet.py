"""`radar-odom fleet` on a local multi-node Ray cluster against the serial `radar-odom run` loop, same run.

    python benchmarks/fleet.py                      # 8 simulated drives of 60 sweeps, 2 nodes of 1 CPU; ~6 min

``--recordings`` simulated urban drives (seeds 100, 101, …; ``--frames`` sweeps each) are written once into
``--workdir`` (reused when there). A Ray cluster of ``--nodes`` node processes (head + workers,
``ray.cluster_utils.Cluster``, ``--cpus-per-node`` CPUs each) is started once, its start-up timed. Then,
``--repeats`` times in turn:

- serial: ``radar-odom run REC -o …`` as a new process per recording, one after the other (the shell loop
  a user writes: each pays interpreter start, imports and the model load; default threads);
- fleet: ``radar-odom fleet REC… -o … --address <cluster>`` as one process, into a fresh OUT (nothing kept);
- fleet, local: ``radar-odom fleet REC… -o …`` with no address: the command starts (and stops) its own
  local Ray of one node with this machine's CPUs, and that start is in its time.

Printed: median and p90 over the repeats of each loop's wall time, the ratio of the medians (serial / fleet,
measured in the same rounds), and from the last fleet's ``fleet.csv``: recordings and sweeps/s per node, the
median seconds a recording takes inside its worker, and the overhead per recording (fleet wall × workers /
recordings − that median: driver start, Ray connection, actor start and model loads, scheduling, the tail).
``--markdown FILE`` also writes the table.
"""
from __future__ import annotations

import argparse
import csv
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def simulate(workdir: Path, n: int, frames: int) -> list[Path]:
    from radar_odom.sim import write_drive

    drives = []
    for k in range(n):
        path = workdir / f"drive{k:02d}-{frames}f"
        if not (path / "radar.timestamps").is_file():
            shutil.rmtree(path, ignore_errors=True)
            write_drive(path, seed=100 + k, frames=frames, progress=False)
        drives.append(path)
    return drives


def cli(*args) -> list[str]:
    return [sys.executable, "-m", "radar_odom", *map(str, args)]


def serial_loop(drives, out: Path) -> float:
    t0 = time.perf_counter()
    for d in drives:
        subprocess.run(cli("run", d, "-o", out / d.name), check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def fleet_run(drives, out: Path, address: str | None) -> tuple[float, str]:
    t0 = time.perf_counter()
    where = ["--address", address] if address else []
    done = subprocess.run(cli("fleet", *drives, "-o", out, *where, "--no-progress"),
                          check=True, capture_output=True, text=True)
    return time.perf_counter() - t0, done.stdout


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=8)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--nodes", type=int, default=2)
    ap.add_argument("--cpus-per-node", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "radar-odom-fleet-bench")
    ap.add_argument("--markdown", type=Path, default=None)
    args = ap.parse_args(argv)

    from ray.cluster_utils import Cluster

    args.workdir.mkdir(parents=True, exist_ok=True)
    drives = simulate(args.workdir, args.recordings, args.frames)
    t0 = time.perf_counter()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": args.cpus_per_node})
    for _ in range(args.nodes - 1):
        cluster.add_node(num_cpus=args.cpus_per_node)
    cluster.wait_for_nodes()
    start_s = time.perf_counter() - t0
    serial, fleet, local, said = [], [], [], ""
    try:
        for r in range(args.repeats):
            runs = args.workdir / f"round{r}"
            shutil.rmtree(runs, ignore_errors=True)
            serial.append(serial_loop(drives, runs / "serial"))
            wall, said = fleet_run(drives, runs / "fleet", cluster.address)
            fleet.append(wall)
            local.append(fleet_run(drives, runs / "local", None)[0])
            print(f"round {r + 1}: serial {serial[-1]:.1f} s, fleet {wall:.1f} s, local fleet {local[-1]:.1f} s",
                  flush=True)
    finally:
        cluster.shutdown()
    with open(args.workdir / f"round{args.repeats - 1}" / "fleet" / "fleet.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    workers = int(said.split(" worker(s)")[0].rsplit(" ", 1)[-1])
    inside = np.array([float(r["seconds"]) for r in rows])
    fleet_med = float(np.median(fleet))
    overhead = fleet_med * workers / len(rows) - float(np.median(inside))
    lines = [
        f"{args.recordings} simulated drives × {args.frames} sweeps; Ray cluster of {args.nodes} node processes × "
        f"{args.cpus_per_node} CPU (started in {start_s:.1f} s, not in the fleet times); {args.repeats} rounds "
        f"interleaved; {os.cpu_count()} logical CPUs, {platform.processor() or platform.machine()}, Python "
        f"{platform.python_version()}",
        "",
        "| loop | median wall s | p90 wall s | per recording s | speed-up (serial / fleet, medians) |",
        "|---|---|---|---|---|",
        f"| serial `radar-odom run` per recording | {np.median(serial):.1f} | {np.percentile(serial, 90):.1f} | "
        f"{np.median(serial) / len(drives):.2f} | 1.00 |",
        f"| `radar-odom fleet --address` ({workers} workers) | {fleet_med:.1f} | {np.percentile(fleet, 90):.1f} | "
        f"{fleet_med / len(drives):.2f} | {np.median(serial) / fleet_med:.2f} |",
        f"| `radar-odom fleet` (no address: starts its own local Ray, {os.cpu_count()} CPUs) | "
        f"{np.median(local):.1f} | {np.percentile(local, 90):.1f} | {np.median(local) / len(drives):.2f} | "
        f"{np.median(serial) / np.median(local):.2f} |",
        "",
        "| node | recordings | sweeps | sweeps/s over the fleet's wall (last round) |",
        "|---|---|---|---|",
    ]
    for node in sorted({r["node"] for r in rows}):
        mine = [r for r in rows if r["node"] == node]
        sweeps = sum(int(r["sweeps"]) for r in mine)
        lines.append(f"| {node} | {len(mine)} | {sweeps} | {sweeps / fleet[-1]:.1f} |")
    lines += ["", f"inside a worker: median {np.median(inside):.2f} s per recording (read, odometry, outputs, plot, "
                  f"manifest); overhead per recording (fleet wall × {workers} workers / {len(rows)} − that): "
                  f"{overhead:.2f} s"]
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
