"""Resident memory of a long `RadarOdometer` stream, measured in a fresh interpreter."""
from __future__ import annotations

import json
import subprocess
import sys

from ..errors import RadarOdomError
from .stats import peak_rss_mb, rss_mb
from .sweeps import PROFILE_SEED, cycled, decode_png, parse_sweep, simulated_pngs, sweep_period_us

RSS_CHILD = r"""
import json, sys
from radar_odom.latency.memory import rss_stream_here
print(json.dumps(rss_stream_here(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]))))
"""


def rss_stream(model_path, steps: int = 1000, threads: int = 2, every: int = 50) -> dict:
    """`rss_stream_here` in a fresh interpreter, so that nothing else counts towards its RSS."""
    proc = subprocess.run([sys.executable, "-c", RSS_CHILD, str(model_path), str(steps), str(threads), str(every)],
                          capture_output=True, text=True, check=False)
    if proc.returncode:
        raise RadarOdomError(f"the RSS stream of {model_path} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def rss_stream_here(model_path, steps: int, threads: int = 2, every: int = 50, distinct: int = 16) -> dict:
    """Run ``steps`` sweeps through `RadarOdometer` (PNG decode → parse → step), sampling
    ``VmRSS`` every ``every`` steps. ``distinct`` simulated sweeps are cycled with their
    timestamps moved on, so the stream is continuous and holds only PNG bytes in memory.

    Returns ``{"steps", "samples": [[step, MiB], ...], "peak_mb", "growth_mb"}`` where
    ``growth_mb`` is the RSS change from the first sample after 10 % of the stream to the end.
    """
    from ..odometry.odometer import RadarOdometer

    pngs = simulated_pngs(distinct, seed=PROFILE_SEED + 1)
    odo = RadarOdometer(model_path, threads=threads, max_gap_s=10.0)
    period_us = sweep_period_us([parse_sweep(decode_png(b)).timestamp_us for b in pngs[:2]])
    samples = []
    for i in range(steps):
        odo.step(cycled(parse_sweep(decode_png(pngs[i % distinct])), i, distinct, period_us))
        if (i + 1) % every == 0 or i == 0:
            samples.append([i + 1, rss_mb()])
    start = next((s for s in samples if s[0] >= steps // 10), samples[0])
    return {"steps": steps, "every": every, "samples": samples, "peak_mb": peak_rss_mb(),
            "growth_mb": float(samples[-1][1] - start[1]), "growth_from_step": start[0]}

