"""End-to-end sweeps/s on files: a recording on disk streamed through `iter_estimates`, with
the reading pipelined on a worker thread and without (the issue-14 target: wall per sweep
≤ 1.15 × max(read, step))."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from .sweeps import decode_png, parse_sweep


def write_recording(pngs: list[bytes], folder, count: int) -> list[Path]:
    """``count`` sweep files named by their first azimuth's time, as an Oxford ``radar/``
    folder holds them; the ``pngs`` are cycled with their timestamps moved on, so the stream is
    continuous (re-encoding costs nothing at run time: only the files are read back)."""
    from dataclasses import replace

    import cv2
    import numpy as np

    from ..formats.oxford import scan_to_image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scans = [parse_sweep(decode_png(b)) for b in pngs]
    period_us = int(np.median(np.diff([s.timestamp_us for s in scans]))) if len(scans) > 1 else 250_000
    span_us = period_us * len(scans)
    paths = []
    for i in range(count):
        scan = scans[i % len(scans)]
        shift = (i // len(scans)) * span_us
        if shift:
            scan = replace(scan, timestamps_us=scan.timestamps_us + shift)
        path = folder / f"{scan.timestamp_us}.png"
        if not cv2.imwrite(str(path), scan_to_image(scan)):
            raise OSError(f"could not write {path}")
        paths.append(path)
    return paths


def file_throughput(model_path, pngs: list[bytes], *, sweeps: int = 100, threads: int = 2,
                    prefetch: int = 2, warmup: int = 5) -> dict:
    """`radar_odom.pipeline.throughput` of ``sweeps`` files through a fresh `RadarOdometer`,
    pipelined (``prefetch``) and serial (prefetch 0), as dicts keyed "pipelined" / "serial"."""
    from ..odometer import RadarOdometer
    from ..pipeline import iter_estimates, throughput

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_recording(pngs, Path(tmp) / "radar", sweeps + warmup)
        odo = RadarOdometer(model_path, threads=threads, max_gap_s=10.0)
        for label, depth in (("pipelined", prefetch), ("serial", 0)):
            odo.reset()
            with iter_estimates(paths[:warmup], odo, prefetch=0) as warm:
                for _ in warm:
                    pass
            t0 = time.perf_counter()
            with iter_estimates(paths[warmup:], odo, prefetch=depth) as stream:
                for _ in stream:
                    pass
            wall = time.perf_counter() - t0
            out[label] = throughput(wall, stream.load_seconds, stream.step_seconds).as_dict()
    return out
