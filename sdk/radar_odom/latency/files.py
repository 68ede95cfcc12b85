"""End-to-end sweeps/s on files: a recording on disk streamed through `iter_estimates`, with
the reading pipelined on a worker thread and without (the issue-14 target: wall per sweep
≤ 1.15 × max(read, step))."""
from __future__ import annotations

import tempfile
from pathlib import Path

from .sweeps import cycled, decode_png, parse_sweep, sweep_period_us


def write_recording(pngs: list[bytes], folder, count: int) -> list[Path]:
    """``count`` sweep files named by their first azimuth's time, as an Oxford ``radar/``
    folder holds them; the ``pngs`` are cycled with their timestamps moved on, so the stream is
    continuous (re-encoding costs nothing at run time: only the files are read back)."""
    import cv2

    from ..io.oxford import scan_to_image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scans = [parse_sweep(decode_png(b)) for b in pngs]
    period_us = sweep_period_us([s.timestamp_us for s in scans])
    paths = []
    for i in range(count):
        scan = cycled(scans[i % len(scans)], i, len(scans), period_us)
        path = folder / f"{scan.timestamp_us}.png"
        if not cv2.imwrite(str(path), scan_to_image(scan)):
            raise OSError(f"could not write {path}")
        paths.append(path)
    return paths


def timed_stream(paths: list, odo, *, warmup: int, prefetch: int):
    """Stream ``paths[warmup:]`` through ``odo`` with ``prefetch`` read-ahead, after the first ``warmup``
    files ran through it serially (sessions and caches warm, not timed); returns the finished stream,
    which timed its own loop (``wall_s``, ``load_seconds``, ``step_seconds``, ``throughput()``)."""
    from ..odometry.pipeline import iter_estimates

    with iter_estimates(paths[:warmup], odo, prefetch=0) as warm:
        for _ in warm:
            pass
    with iter_estimates(paths[warmup:], odo, prefetch=prefetch) as stream:
        for _ in stream:
            pass
    return stream


def file_throughput(model_path, pngs: list[bytes], *, sweeps: int = 100, threads: int = 2,
                    prefetch: int = 2, warmup: int = 5) -> dict:
    """`radar_odom.odometry.pipeline.throughput` of ``sweeps`` files through a fresh `RadarOdometer`,
    pipelined (``prefetch``) and serial (prefetch 0), as dicts keyed "pipelined" / "serial"."""
    from ..odometry.odometer import RadarOdometer

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_recording(pngs, Path(tmp) / "radar", sweeps + warmup)
        odo = RadarOdometer(model_path, threads=threads, max_gap_s=10.0)
        for label, depth in (("pipelined", prefetch), ("serial", 0)):
            odo.reset()
            stream = timed_stream(paths, odo, warmup=warmup, prefetch=depth)
            out[label] = stream.throughput().as_dict()  # the stream times its own loop
    return out
