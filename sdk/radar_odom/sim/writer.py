"""Write a simulated drive in the Oxford Radar RobotCar layout, through the same writers the
readers are tested against:

    OUT/radar/<first-azimuth µs>.png        Oxford sweep PNGs (`radar_odom.io.write_scan`)
    OUT/radar.timestamps                    "<µs> <valid>" per sweep
    OUT/gt/radar_odometry.csv               Oxford relative poses (source = later sweep)
    OUT/labels/<first-azimuth µs>.png       uint8 [A, B] static-world label (255 = static)

Deterministic: the same seed, scenario and config give byte-identical files.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .config import Scenario, SimConfig, SimConfigError
from .simulator import Simulator

LABELS_DIR = "labels"


# bytes one simulated sweep takes on disk: its Oxford-layout PNG and its label (570 kB measured), with margin
BYTES_PER_FRAME = 700_000


def check_output_folder(seq: Path, frames: int) -> None:
    """`OutputError` before anything is simulated where ``seq`` cannot hold the drive: a file in its place
    (or in its path), a folder that cannot be created or written, or less free space than ``frames`` sweeps
    take (`BYTES_PER_FRAME` each)."""
    import os
    import shutil

    from ..errors import OutputError

    if seq.exists() and not seq.is_dir():
        raise OutputError(f"{seq}: exists and is not a folder; give simulate a folder to write (new or existing)")
    try:
        seq.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{seq}: cannot create the sequence folder ({exc.strerror or exc}); give another "
                          "path") from None
    if not os.access(seq, os.W_OK):
        raise OutputError(f"{seq}: the folder is not writable; give another path")
    need = frames * BYTES_PER_FRAME
    free = shutil.disk_usage(seq).free
    if need > free:
        raise OutputError(f"{seq}: {frames} sweeps take about {need / 1e9:.1f} GB ({BYTES_PER_FRAME / 1e3:.0f} kB "
                          f"each) and the disk has {free / 1e9:.1f} GB free; simulate fewer frames or free space")


def write_drive(out_dir, seed: int, frames: int, scenario: str | Scenario = "urban",
                config: SimConfig | None = None, progress: bool = True) -> Path:
    """Simulate a drive and write it to ``out_dir`` (created if missing).

    Returns the sequence folder. ``progress`` shows a bar on stderr. Rewriting the same drive
    into its folder is fine; a folder holding sweeps of another drive raises `SimConfigError`
    (mixed sweeps would read back as one broken recording).
    """
    from .._progress import progress as bar
    from ..io import oxford_gt_rows, write_oxford_ground_truth, write_radar_timestamps, write_scan

    sim = Simulator(seed, frames, scenario, config)
    seq = Path(out_dir)
    check_output_folder(seq, frames)
    planned = {f"{int(sim.timestamps_us(k)[0])}.png" for k in range(frames)}
    foreign = [p.name for p in (seq / "radar").glob("*.png") if p.name not in planned]
    if foreign:
        raise SimConfigError(
            f"{seq / 'radar'} already holds {len(foreign)} sweeps of another drive (e.g. {foreign[0]}); "
            "write into an empty folder or delete the old one"
        )
    (seq / "radar").mkdir(parents=True, exist_ok=True)
    (seq / LABELS_DIR).mkdir(parents=True, exist_ok=True)
    names, mids, rel, sweep_ok = [], [], [], []
    frames_iter = bar(iter(sim), total=frames, desc=f"simulating {sim.scenario.name}", unit="sweep",
                      disable=not progress)
    for fr in frames_iter:
        name = fr.scan.timestamp_us
        write_scan(seq / "radar" / f"{name}.png", fr.scan)
        label_path = seq / LABELS_DIR / f"{name}.png"
        if not cv2.imwrite(str(label_path), fr.static_label):
            raise OSError(f"{label_path}: OpenCV could not write the label PNG; check the folder is writable")
        names.append(name)
        ts = fr.scan.timestamps_us
        mids.append(int(ts[0]) + int(np.round(np.mean(ts - ts[0]))))  # exact: offsets are small
        sweep_ok.append(bool(fr.scan.valid.any()))
        if fr.pose_rel is not None:
            rel.append(fr.pose_rel)
    write_radar_timestamps(seq, names, sweep_ok)
    write_oxford_ground_truth(seq, oxford_gt_rows(names, mids, np.asarray(rel).reshape(-1, 3)))
    return seq
