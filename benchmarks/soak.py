"""Soak test: one `RadarOdometer` stepped for a long time; does memory or latency creep?

    python benchmarks/soak.py [--steps 10000] [--model cart-0.4] [--threads N] [--pool 48]
                              [--bad-every 0] [--json soak.json] [--check]

A pool of ``--pool`` simulated sweeps (one urban drive at full CTS350-X resolution, 400 × 3768)
is cycled with fresh timestamps 0.25 s apart, so the stream never ends: each lap restarts the
drive, a jump the motion prior sees once per lap (gated or taken), which is fine for a soak. With
``--bad-every N`` every N-th sweep is replaced by a blank one and every (N+1)-th by a skipped
(unreadable) one, so the degenerate, bridged and skip paths are soaked too.

Measured per step: wall-clock latency of ``odo.step`` and the process's resident set size
(``/proc/self/statm``, or ``ru_maxrss`` where that is missing). Reported (markdown, and JSON with
``--json``):

- **RSS growth after step 1000**: RSS at the end minus RSS at step 1000, and the least-squares
  slope over those steps (MB per 1000 steps). The odometer keeps every pose of the stream (its
  trajectory: ~0.2 kB a step), so a little growth is by design; ``--check`` fails above 5 MB.
- **p99 latency drift**: p99 of the last 1000 steps against p99 of steps 1000–2000, in %
  (``--check`` fails above 10 %). On a shared machine other load moves this; the load averages
  at the start and end are printed beside it.

With fewer steps (a smoke run, e.g. ``--steps 300``) the warm-up and the windows shrink to a
fifth of the run each. Simulating the pool takes ~0.3 s a sweep; the steps then run at the
model's speed (cart-0.4: ~20–40 ms a step on one modern core).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import sys
import time

import numpy as np

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Resident set size now (Linux ``/proc/self/statm``), else the peak from ``getrusage``."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def load_average() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def sweep_pool(n: int, seed: int):
    from radar_odom.sim import simulate_drive

    return [f.scan for f in simulate_drive(seed=seed, frames=n, scenario="urban")]


def restamped(scan, t0_us: int):
    """``scan`` with its azimuth times moved to start at ``t0_us`` (same spacing)."""
    ts = scan.timestamps_us - scan.timestamps_us[0] + t0_us
    return dataclasses.replace(scan, timestamps_us=ts)


def blank_like(scan):
    return dataclasses.replace(scan, power=np.zeros_like(scan.power))


def soak(steps: int, model: str, threads: int | None, pool_size: int, bad_every: int, seed: int,
         progress: bool = True) -> dict:
    from radar_odom import RadarOdometer
    from radar_odom.model_zoo import resolve_model

    t_sim = time.perf_counter()
    pool = sweep_pool(pool_size, seed)
    t_sim = time.perf_counter() - t_sim
    odo = RadarOdometer(resolve_model(model), threads=threads)
    period_us = 250_000
    t0 = int(pool[0].timestamps_us[0])
    lat = np.empty(steps)
    rss = np.empty(steps)
    flags = {"degenerate": 0, "bridged": 0, "gated": 0}
    load_start = load_average()
    wall0 = time.perf_counter()
    for k in range(steps):
        ts = t0 + k * period_us
        bad = bad_every > 0 and k > 0 and k % bad_every == 0
        skip = bad_every > 0 and k > 1 and k % (bad_every + 1) == 0
        if skip:
            t = time.perf_counter()
            est = odo.skip(ts, "unreadable")
        else:
            scan = restamped(pool[k % pool_size], ts)
            if bad:
                scan = blank_like(scan)
            t = time.perf_counter()
            est = odo.step(scan)
        lat[k] = time.perf_counter() - t
        rss[k] = rss_bytes()
        if est is not None:
            for f in flags:
                flags[f] += f in est.flags
        if progress and (k + 1) % max(1, steps // 20) == 0:
            print(f"  step {k + 1}/{steps}: {1e3 * lat[k]:.1f} ms, RSS {rss[k] / 2**20:.1f} MB",
                  file=sys.stderr, flush=True)
    wall = time.perf_counter() - wall0
    return summarise(lat, rss, steps, model, threads, pool_size, bad_every, t_sim, wall, flags,
                     load_start, load_average(), len(odo.trajectory))


def summarise(lat, rss, steps, model, threads, pool_size, bad_every, t_sim, wall, flags, load_start,
              load_end, trajectory_len) -> dict:
    warm = min(1000, steps // 5)
    window = min(1000, max(1, steps // 5))
    after = np.arange(warm, steps)
    mb = rss / 2**20
    slope = float(np.polyfit(after, mb[after], 1)[0] * 1000) if after.size > 1 else float("nan")
    first = lat[warm:warm + window]
    last = lat[steps - window:]
    p99_first, p99_last = float(np.percentile(first, 99)), float(np.percentile(last, 99))
    return {
        "model": model, "steps": steps, "threads": threads, "pool": pool_size, "bad_every": bad_every,
        "warmup_steps": warm, "window_steps": window,
        "rss_mb_at_warmup": float(mb[warm]), "rss_mb_end": float(mb[-1]),
        "rss_growth_mb_after_warmup": float(mb[-1] - mb[warm]),
        "rss_slope_mb_per_1000_steps": slope,
        "latency_ms_median": float(1e3 * np.median(lat[warm:])),
        "latency_ms_p99_first_window": 1e3 * p99_first, "latency_ms_p99_last_window": 1e3 * p99_last,
        "p99_drift_percent": 100.0 * (p99_last - p99_first) / p99_first,
        "seconds_simulating_pool": t_sim, "seconds_stepping": wall,
        "flags": flags, "trajectory_length": trajectory_len,
        "load_average_start": load_start, "load_average_end": load_end,
    }


def report(r: dict) -> str:
    w, n = r["warmup_steps"], r["window_steps"]
    rows = [
        ("steps (model, threads)", f"{r['steps']} ({r['model']}, {r['threads'] or 'physical cores'})"),
        (f"RSS at step {w} → end", f"{r['rss_mb_at_warmup']:.1f} → {r['rss_mb_end']:.1f} MB"),
        (f"RSS growth after step {w}", f"{r['rss_growth_mb_after_warmup']:+.2f} MB "
                                       f"(slope {r['rss_slope_mb_per_1000_steps']:+.3f} MB / 1000 steps)"),
        ("latency median", f"{r['latency_ms_median']:.1f} ms"),
        (f"p99 latency, steps {w}–{w + n} vs last {n}",
         f"{r['latency_ms_p99_first_window']:.1f} → {r['latency_ms_p99_last_window']:.1f} ms "
         f"({r['p99_drift_percent']:+.1f} %)"),
        ("flags (degenerate / bridged / gated)",
         f"{r['flags']['degenerate']} / {r['flags']['bridged']} / {r['flags']['gated']}"),
        ("load average start → end", f"{r['load_average_start']} → {r['load_average_end']}"),
    ]
    return "\n".join(["| soak | |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=10_000, help="odometry steps (default 10000)")
    ap.add_argument("--model", default="cart-0.4", help="shipped model name or .onnx path (default cart-0.4)")
    ap.add_argument("--threads", type=int, default=None, help="onnxruntime threads (default: physical cores)")
    ap.add_argument("--pool", type=int, default=48, help="simulated sweeps cycled (default 48)")
    ap.add_argument("--bad-every", type=int, default=0,
                    help="inject a blank sweep every N steps and a skipped one every N+1 (default 0: none)")
    ap.add_argument("--seed", type=int, default=9001, help="simulator seed (default 9001)")
    ap.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if RSS grows ≥ 5 MB after warm-up or p99 latency drifts ≥ 10 %%")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = ap.parse_args(argv)
    if args.steps < 10 or args.pool < 2:
        ap.error("--steps must be ≥ 10 and --pool ≥ 2")
    r = soak(args.steps, args.model, args.threads, args.pool, args.bad_every, args.seed, not args.quiet)
    print(report(r))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(r, f, indent=2)
    if args.check:
        ok = r["rss_growth_mb_after_warmup"] < 5.0 and r["p99_drift_percent"] < 10.0
        print("check:", "pass" if ok else "FAIL (RSS growth ≥ 5 MB or p99 drift ≥ 10 %)")
        return 0 if ok else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
