"""Write a simulated drive in the Oxford Radar RobotCar layout, through the same writers the
readers are tested against:

    OUT/radar/<first-azimuth µs>.png        Oxford sweep PNGs (`radar_odom.io.write_scan`)
    OUT/radar.timestamps                    "<µs> <valid>" per sweep
    OUT/gt/radar_odometry.csv               Oxford relative poses (source = later sweep)
    OUT/labels/<first-azimuth µs>.png       uint8 [A, B] static-world label (255 = static)

Deterministic: the same seed, scenario and config give byte-identical files.

With a host clock other than ``perfect`` (`radar_odom.sim.host_clock`, ``host_clock=``), the folder is what
that host would have recorded:

    OUT/radar/<name µs>.png                 only the sweeps the host received, each named by its host stamp,
                                            its azimuth times shifted by the same amount (`host_stamps.timed`)
    OUT/radar.timestamps                    those names in reception order (they may go back)
    OUT/gt/radar_odometry.csv               the truth between consecutive kept sweeps (reception order):
                                            ``*_radar_timestamp`` the names, ``source/destination_timestamp``
                                            the sweeps' TRUE mid times (the time the pose is the truth at)
    OUT/gt/dropped.csv                      ``index,true_us``: the sweeps dropped (index into the drive)
    OUT/gt/true_timestamps.csv              ``index,true_us,host_us,name_us`` per kept sweep, reception order:
                                            true first-azimuth time, the host's stamp, the file name

A name is the host stamp, except that a stamp already written (a duplicated stamp) takes the next free
µs after it (`file_names`): Oxford names must be unique.
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
                config: SimConfig | None = None, progress: bool = True, host_clock=None) -> Path:
    """Simulate a drive and write it to ``out_dir`` (created if missing).

    Returns the sequence folder. ``progress`` shows a bar on stderr. Rewriting the same drive
    into its folder is fine; a folder holding sweeps of another drive raises `SimConfigError`
    (mixed sweeps would read back as one broken recording). ``host_clock``: a preset name or a
    `radar_odom.sim.host_clock.HostClock`; None or ``"perfect"`` writes the true stamps (the files are
    the same as without it), another clock writes what that host would have recorded (module docstring;
    its draws are seeded by ``seed``).
    """
    from .._progress import progress as bar
    from ..io import oxford_gt_rows, write_oxford_ground_truth, write_radar_timestamps, write_scan

    clock = None
    if host_clock is not None:
        from .host_clock import host_clock as get_clock

        clock = get_clock(host_clock)
        if clock.is_perfect:
            clock = None
    sim = Simulator(seed, frames, scenario, config)
    seq = Path(out_dir)
    check_output_folder(seq, frames)
    if clock is not None:
        return _write_clocked(seq, sim, clock, progress)
    planned = {f"{int(sim.timestamps_us(k)[0])}.png" for k in range(frames)}
    _refuse_foreign(seq, planned)
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


def _refuse_foreign(seq: Path, planned: set) -> None:
    foreign = [p.name for p in (seq / "radar").glob("*.png") if p.name not in planned]
    if foreign:
        raise SimConfigError(
            f"{seq / 'radar'} already holds {len(foreign)} sweeps of another drive (e.g. {foreign[0]}); "
            "write into an empty folder or delete the old one"
        )


def file_names(stamps_us) -> np.ndarray:
    """int64[K] Oxford file names (µs) for host stamps in reception order: each stamp itself, except that
    a stamp already taken (a duplicated stamp, or rarely a backwards one landing on an earlier name) takes
    the next free µs after it."""
    used: set[int] = set()
    names = []
    for s in np.asarray(stamps_us, dtype=np.int64).tolist():
        while s in used:
            s += 1
        used.add(s)
        names.append(s)
    return np.asarray(names, dtype=np.int64)


def yaw_rates_rps(sim: Simulator, dt_s: float = 0.05) -> np.ndarray:
    """float64[N] the ego's yaw rate (rad/s) at each sweep's mid time, by central difference."""
    t_mid = np.array([float(np.mean(sim.drive_time_s(sim.timestamps_us(k)))) for k in range(sim.frames)])
    _, before = sim.drive.pose_at(t_mid - dt_s)
    _, after = sim.drive.pose_at(t_mid + dt_s)
    return np.angle(np.exp(1j * (after - before))) / (2 * dt_s)


DROPPED_CSV = "dropped.csv"
TRUE_TIMES_CSV = "true_timestamps.csv"


def _write_clocked(seq: Path, sim: Simulator, clock, progress: bool) -> Path:
    """`write_drive` through a host clock (module docstring)."""
    from .._progress import progress as bar
    from ..io import oxford_gt_rows, write_oxford_ground_truth, write_radar_timestamps, write_scan
    from ..se2 import invert, to_xyyaw
    from .host_stamps import timed

    true_us = np.array([int(sim.timestamps_us(k)[0]) for k in range(sim.frames)], dtype=np.int64)
    clocked = clock.apply(true_us, seed=sim.seed, turn_rate_rps=yaw_rates_rps(sim))
    names = file_names(clocked.stamps_us)
    _refuse_foreign(seq, {f"{n}.png" for n in names.tolist()})
    (seq / "radar").mkdir(parents=True, exist_ok=True)
    (seq / LABELS_DIR).mkdir(parents=True, exist_ok=True)
    mids, rel, sweep_ok = [], [], []
    prev = None
    kept = bar(list(zip(clocked.keep.tolist(), names.tolist())), desc=f"simulating {sim.scenario.name} ({clock.name})",
               unit="sweep", disable=not progress)
    for k, name in kept:
        fr = sim.frame(k)
        ts = fr.scan.timestamps_us
        mids.append(int(ts[0]) + int(np.round(np.mean(ts - ts[0]))))  # the true mid time
        if prev is not None:
            rel.append(to_xyyaw(invert(prev) @ fr.pose_mid))
        prev = fr.pose_mid
        write_scan(seq / "radar" / f"{name}.png", timed([fr.scan], [name])[0])
        label_path = seq / LABELS_DIR / f"{name}.png"
        if not cv2.imwrite(str(label_path), fr.static_label):
            raise OSError(f"{label_path}: OpenCV could not write the label PNG; check the folder is writable")
        sweep_ok.append(bool(fr.scan.valid.any()))
    write_radar_timestamps(seq, names, sweep_ok)
    write_oxford_ground_truth(seq, oxford_gt_rows(names, mids, np.asarray(rel).reshape(-1, 3)))
    gt = seq / "gt"
    (gt / DROPPED_CSV).write_text("index,true_us\n" + "".join(
        f"{k},{true_us[k]}\n" for k in clocked.dropped.tolist()))
    (gt / TRUE_TIMES_CSV).write_text("index,true_us,host_us,name_us\n" + "".join(
        f"{k},{true_us[k]},{s},{n}\n"
        for k, s, n in zip(clocked.keep.tolist(), clocked.stamps_us.tolist(), names.tolist())))
    return seq
