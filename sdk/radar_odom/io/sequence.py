"""`read_sequence`: a recording folder as time-ordered sweeps with ground truth where present.

Ground truth is always returned in the Oxford relative convention (see `radar_odom.se2`):
``gt_relative[k]`` = ``(x, y, yaw)`` of sweep k+1 in sweep k, x forward, y right, z down.

- Oxford: rows of ``gt/radar_odometry.csv`` matched by ``(destination, source)_radar_timestamp``
  = the two PNG names. Sweeps come in the order of their names, or of ``radar.timestamps`` where it
  lists the same sweeps in another order (a host's reception order, stamps going back; `StampWarning`).
- Boreas: absolute ENU poses of ``applanix/radar_poses.csv`` at the nearest ``GPSTime`` to each
  file name (the sweep's middle time), converted as in `._zup`.
- MulRan: absolute poses of ``global_pose.csv`` at the nearest stamp to each sweep's middle time
  (file name − ``sweep_period_s`` / 2; the true mean azimuth time differs by < 1 ms), converted
  as in `._zup`.
- RADIATE: none: sweeps are ordered by frame number and timed by ``Navtech_Polar.txt``, those host
  stamps fitted on the sensor's period (`.timebase`, ``Sequence.time_base``). Where
  the sequence has a ``GPS_IMU_Twist/`` folder, ``Sequence.reference`` is its GNSS/INS track
  (`.gnss_ins.GnssInsTrack`), but it is not turned into ``gt_relative``: its clock is not the
  radar's (+1.7 s on one drive, ≈ 64 s on another) and its heading is not the vehicle's axis,
  so the clock offset must be resolved first (`.gnss_ins.estimate_clock_offset_s`,
  `.gnss_ins.estimate_heading_offset_rad`, then `.gnss_ins.relative_poses_at`).

A pair without ground truth gives a NaN row; no ground truth at all gives ``None``.
"""
from __future__ import annotations

import functools
import inspect
import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import ConfigError, GroundTruthWarning, SequenceError, StampWarning
from ..scan import RadarScan
from ..se2 import chain_relative
from . import boreas, gnss_ins, mulran, oxford, radiate
from ._layout import name_timestamp, to_microseconds
from ._zup import nearest_poses, oxford_relative_from_zup
from .scan_io import FORMATS, layout_evidence, load_scan, warn_format_contradiction
from .timebase import TimeBase, fit_time_base

# MulRan keeps sweeps under sensor_data/radar/ in the release, at the top level in some copies;
# Oxford-form copies come first because they carry real per-azimuth times and encoder angles.
_MULRAN_DIRS = tuple(
    Path(*parts, name)
    for name in (mulran.OXFORD_FORM_DIR, mulran.RAW_DIR)
    for parts in ((), ("sensor_data", "radar"))
)


@dataclass(frozen=True)
class Frame:
    """One sweep of a sequence.

    Attributes:
        scan: the decoded sweep.
        timestamp_us: its file-name time in µs (Oxford: first azimuth; Boreas: middle of the
            sweep; MulRan: end of the sweep; RADIATE: the frame's time in ``Navtech_Polar.txt``,
            taken as the first azimuth's).
        index: position in the sequence (time order).
        gt_pose_rel: float64[3] Oxford ``(x, y, yaw)`` of this sweep in the previous one, or
            None (first sweep, or no ground truth for this pair).
    """

    scan: RadarScan
    timestamp_us: int
    index: int
    gt_pose_rel: np.ndarray | None


class Sequence:
    """Sweeps of a recording in time order; each is decoded only when asked for.

    ``len(seq)``, ``seq[i]`` and iteration give `Frame` objects. ``timestamps_us`` int64[N]
    (file-name times in µs; RADIATE: the frame times fitted on the sensor's period, `time_base`,
    unless read with ``repair_stamps=False``), ``stamp_corrections_us`` int64[N] (recorded − used
    time of each sweep: > 0 a late stamp, < 0 an early one; zeros where used as recorded),
    ``time_base`` (the `radar_odom.io.timebase.TimeBase` the times come from, or None: its period
    and sweep indices tell a gap from a late stamp), ``paths`` (the PNGs), ``gt_relative``
    float64[N−1, 3] or None, ``format``, ``root``, ``reference`` (RADIATE's GNSS/INS track or None,
    read on first use).
    """

    def __init__(self, root: Path, format: str, paths, timestamps_us, gt_relative, load_kwargs: dict,
                 stamp_corrections_us=None, time_base: TimeBase | None = None):
        self.root = Path(root)
        self.format = format
        self.paths = tuple(paths)
        self.timestamps_us = np.asarray(timestamps_us, dtype=np.int64)
        self.stamp_corrections_us = (np.zeros_like(self.timestamps_us) if stamp_corrections_us is None
                                     else np.asarray(stamp_corrections_us, dtype=np.int64))
        self.gt_relative = gt_relative
        self.time_base = time_base
        self._load_kwargs = dict(load_kwargs)

    def __len__(self) -> int:
        return len(self.paths)

    def __repr__(self) -> str:
        gt = "no ground truth" if self.gt_relative is None else "ground truth"
        return f"Sequence({str(self.root)!r}, format={self.format!r}, {len(self)} sweeps, {gt})"

    def scan(self, index: int) -> RadarScan:
        """Decode sweep ``index`` (its azimuth times moved by the sweep's stamp correction, if any)."""
        scan = load_scan(self.paths[index], self.format, **self._load_kwargs)
        late = int(self.stamp_corrections_us[index])
        return replace(scan, timestamps_us=scan.timestamps_us - late) if late else scan

    def __getitem__(self, index: int) -> Frame:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"sweep {index} out of range for a sequence of {n}")
        index %= n
        rel = None
        if index > 0 and self.gt_relative is not None and np.all(np.isfinite(self.gt_relative[index - 1])):
            rel = self.gt_relative[index - 1].copy()
        return Frame(self.scan(index), int(self.timestamps_us[index]), index, rel)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    @functools.cached_property
    def reference(self) -> gnss_ins.GnssInsTrack | None:
        """RADIATE: the GNSS/INS track of ``SEQ/GPS_IMU_Twist/`` (on its own clock, see the module
        docstring), None where the folder is absent; None for the other formats.

        Read on first use (a few thousand small files), so opening a sequence stays cheap;
        a garbled GNSS/INS file raises `SequenceError` here, naming it.
        """
        if self.format != "radiate":
            return None
        return gnss_ins.read_radiate_gnss_ins(self.root)

    def gt_absolute(self) -> np.ndarray | None:
        """float64[N, 3, 3] ground-truth poses chained from the first sweep (identity), or None.

        A pair without ground truth makes every later pose NaN: relative poses cannot bridge it.
        """
        if self.gt_relative is None:
            return None
        return chain_relative(self.gt_relative)


def _sweep_files(folder: Path) -> tuple[list[Path], np.ndarray]:
    """PNG paths in time order and their file-name times in µs."""
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".png" and p.is_file()]
    if not files:
        raise SequenceError(f"{folder}: holds no radar PNGs")
    stamps = [name_timestamp(p) for p in files]
    bad = [p.name for p, s in zip(files, stamps) if s is None]
    if bad:
        raise SequenceError(
            f"{folder}: sweep file names must be integer timestamps, got {', '.join(sorted(bad)[:3])}"
        )
    us = to_microseconds(np.array(stamps, dtype=np.int64))
    order = np.argsort(us, kind="stable")
    return [files[i] for i in order], us[order]


def _reception_order(root: Path, paths: list[Path], stamps: np.ndarray) -> tuple[list[Path], np.ndarray]:
    """Oxford: the sweeps in the order ``radar.timestamps`` lists them, where that is not the names' order.

    A recording host writes the time file in the order it received the sweeps, and names each sweep by
    its stamp, which may go back (a stamp late by more than a period: `radar_odom.sim.host_clock`). Sorted by
    name, such a sweep would come after the one received after it, and neither pair's ground truth (rows keyed
    by consecutive sweeps) would be found. The file is taken only where it lists every PNG once and nothing
    else; otherwise (no file, a garbled one, another folder's) the names' order stays, as before. A
    `StampWarning` says where the time goes back: the odometer refuses such a sweep (`StreamError`), a run
    with ``on_error="skip"`` leaves it out.
    """
    listing = root / "radar.timestamps"
    if not listing.is_file():
        return paths, stamps
    try:
        listed = [int(line.split()[0]) for line in listing.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError, ValueError):
        return paths, stamps
    listed_us = to_microseconds(np.array(listed, dtype=np.int64))
    if len(listed_us) != len(stamps) or not np.array_equal(np.sort(listed_us), stamps) \
            or np.array_equal(listed_us, stamps):
        return paths, stamps
    index = {s: i for i, s in enumerate(stamps.tolist())}
    order = [index[s] for s in listed_us.tolist()]
    back = np.flatnonzero(np.diff(listed_us) <= 0) + 1
    warnings.warn(
        f"{listing}: lists the sweeps in another order than their names (a recording host's reception order): "
        f"read in that order; the time goes back at {back.size} sweep{'s' if back.size > 1 else ''} "
        f"(first {paths[order[back[0]]].name}, after {paths[order[back[0] - 1]].name}), where the odometry "
        "refuses the sweep (StreamError) or, skipping, leaves it out",
        StampWarning, stacklevel=3)
    return [paths[i] for i in order], listed_us


def _detect(root: Path) -> tuple[str, Path]:
    """(format, sweep folder) of a recording, or `SequenceError`."""
    radar = root / "radar"
    if radar.is_dir():
        return ("boreas" if (root / boreas.POSES_RELPATH.parent).is_dir() else "oxford"), radar
    for rel in _MULRAN_DIRS:
        if (root / rel).is_dir():
            return "mulran", root / rel
    if (root / radiate.POLAR_DIR).is_dir():
        return "radiate", root / radiate.POLAR_DIR
    raise SequenceError(
        f"{root}: no radar sweeps found; expected radar/*.png (Oxford, Boreas), polar/*.png / "
        "polar_oxford_form/*.png (MulRan) or Navtech_Polar/*.png (RADIATE)"
    )


def _sweep_folder(root: Path, fmt: str) -> Path:
    if fmt in ("oxford", "boreas"):
        return root / "radar"
    if fmt == "radiate":
        return root / radiate.POLAR_DIR
    for rel in _MULRAN_DIRS:
        if (root / rel).is_dir():
            return root / rel
    return root / mulran.RAW_DIR  # missing: reported by _sweep_files' caller


def _gt_file(path: Path) -> bool:
    """Whether a ground-truth file is there to read; a `GroundTruthWarning` where the name is taken
    by something that is not a file (a folder, a broken link), which would otherwise pass as no ground truth."""
    if path.is_file():
        return True
    if path.exists() or path.is_symlink():
        what = "a folder" if path.is_dir() else "not a readable file (a broken link or a special file)"
        warnings.warn(f"{path}: found but not used: it is {what}, not a ground-truth file; the recording is read "
                      "without ground truth — put the file there or remove what is in its place",
                      GroundTruthWarning, stacklevel=4)
    return False


def _warn_unused_gt(path: Path, why: str) -> None:
    """A `GroundTruthWarning` for a ground-truth file that was read but matches none of the sweeps:
    without it the recording would silently have no ground truth."""
    warnings.warn(f"{path}: found but not used: {why} The recording is read without ground truth.",
                  GroundTruthWarning, stacklevel=4)


def _oxford_gt(root: Path, stamps_us: np.ndarray) -> np.ndarray | None:
    path = root / oxford.GT_RELPATH
    if not _gt_file(path):
        return None
    table = oxford.read_oxford_ground_truth(path)
    rel = np.full((len(stamps_us) - 1, 3), np.nan)
    matched = 0
    for k, (a, b) in enumerate(zip(stamps_us[:-1].tolist(), stamps_us[1:].tolist())):
        pose = table.get((a, b))
        if pose is not None:
            rel[k] = pose
            matched += 1
    if table and len(rel) and not matched:  # rows left out one by one were warned of as they were read
        _warn_unused_gt(path, (
            f"none of its {len(table)} rows is keyed by two consecutive sweeps' file names "
            "(destination_radar_timestamp, source_radar_timestamp); are its columns in another order than its "
            "header says, or is it another recording's?"))
    return rel


def _zup_gt(path: Path, reader, query_us: np.ndarray, max_gap_us: int) -> np.ndarray | None:
    if not _gt_file(path):
        return None
    stamps, poses = reader(path)
    rel = oxford_relative_from_zup(nearest_poses(query_us, stamps, poses, max_gap_us))
    if len(stamps) and len(rel) and not np.isfinite(rel).all(axis=1).any():
        _warn_unused_gt(path, (
            f"no two consecutive sweeps have a pose stamp within max_pose_gap_s = {max_gap_us / 1e6:g} s of their "
            "time; is it another recording's, or are its stamps in another unit or clock?"))
    return rel


# what read_sequence passes on to load_scan for every sweep
LOAD_OPTIONS = tuple(
    name for name, par in inspect.signature(load_scan).parameters.items() if par.kind is inspect.Parameter.KEYWORD_ONLY
)


def check_load_options(load_kwargs: dict) -> None:
    """`ConfigError` now, at open, for a `load_scan` option that would fail at the first sweep: an
    unknown name (a typo), a resolution or period that is not a positive number of metres / seconds,
    a size that is not an integer ≥ 2, an offset that is not a finite number of metres."""
    unknown = sorted(set(load_kwargs) - set(LOAD_OPTIONS))
    if unknown:
        raise ConfigError(f"unknown sweep option{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                          f"read_sequence passes only {', '.join(LOAD_OPTIONS)} on to load_scan")
    for name, value in load_kwargs.items():
        if value is None:
            continue
        if name in ("num_azimuths", "num_bins"):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2:
                raise ConfigError(f"{name} must be an integer ≥ 2 (or None), got {value!r}")
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value):
            raise ConfigError(f"{name} must be a finite number (or None), got {value!r}")
        if name != "range_offset_m" and value <= 0:
            unit = "seconds" if name.endswith("_s") else "metres per bin"
            raise ConfigError(f"{name} must be > 0 {unit} (or None), got {value!r}")


def check_max_pose_gap_s(value) -> float:
    """``max_pose_gap_s`` as a float, or `ConfigError`: a positive, finite number of seconds."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"max_pose_gap_s must be a positive number of seconds (the furthest a pose stamp may be "
                          f"from a sweep's time; default 0.1), got {value!r}")
    return float(value)


def read_sequence(
    seq_dir, format: str | None = None, *, max_pose_gap_s: float = 0.1, repair_stamps: bool = True, **load_kwargs
) -> Sequence:
    """Open a recording folder (nothing is decoded until a frame is asked for).

    Args:
        seq_dir: the sequence folder (Oxford: ``SEQ/radar/``, ``SEQ/gt/``; Boreas: ``SEQ/radar/``,
            ``SEQ/applanix/``; MulRan: ``SEQ/[sensor_data/radar/]polar[_oxford_form]/``,
            ``SEQ/global_pose.csv``; RADIATE: ``SEQ/Navtech_Polar/``, ``SEQ/Navtech_Polar.txt``).
        format: ``"oxford"``, ``"boreas"``, ``"mulran"``, ``"radiate"`` or None to detect from
            the layout.
        max_pose_gap_s: Boreas/MulRan: a sweep whose nearest pose stamp is further away than
            this has no ground truth (0.1 s: 1 m at 10 m/s, and under half the 0.25 s sweep
            period, so a neighbouring sweep's pose is never taken).
        repair_stamps: RADIATE: time the sweeps by the recording's time base fitted on the sensor's
            period (`radar_odom.io.timebase`, ``Sequence.time_base``): stamps the recording host
            stamped late (the shared city drive has three runs of them, up to 0.26 s late, that look
            like dropped sweeps) or early are put back, the host's jitter goes, dropped sweeps stay
            gaps. The other formats' stamps are the sensor's own and are used as recorded.
        **load_kwargs: passed to `load_scan` for every sweep (e.g. ``range_resolution_m``); checked
            here (`check_load_options`).

    Raises:
        ConfigError: an unknown or impossible sweep option, ``max_pose_gap_s`` not > 0.
        SequenceError: no radar PNGs, names that are not timestamps (RADIATE: frame numbers),
            unreadable ground truth; RADIATE: ``Navtech_Polar.txt`` missing, garbled, not
            increasing or without a line for a sweep.

    Warns:
        GroundTruthWarning: a ground-truth file that is there but not used (a folder in its place,
            rows that match none of the sweeps), besides the rows it leaves out.
        FormatWarning: an explicit ``format`` that the folder layout contradicts (as `load_scan`).
        StampWarning: RADIATE stamps off the sensor's period by more than the host's jitter, or
            dropped sweeps (``repair_stamps``): one warning, the time base's one-line summary.
    """
    check_load_options(load_kwargs)
    max_pose_gap_s = check_max_pose_gap_s(max_pose_gap_s)
    root = Path(seq_dir)
    if not root.is_dir():
        what = "not a folder" if root.exists() else "does not exist"
        raise SequenceError(f"{root}: {what}; give a recording folder holding radar/*.png (Oxford, Boreas), "
                            "polar/*.png or polar_oxford_form/*.png (MulRan) or Navtech_Polar/*.png (RADIATE), or a "
                            "ROS bag (.bag, .mcap, .db3 or a ROS 2 bag folder) with --topic")
    if format is None:
        fmt, folder = _detect(root)
    elif format in FORMATS:
        fmt, folder = format, _sweep_folder(root, format)
    else:
        raise ConfigError(f"unknown radar format {format!r}; choose one of {', '.join(FORMATS)} or None")
    if not folder.is_dir():
        raise SequenceError(f"{root}: no {folder.name}/ folder of radar PNGs for format {fmt!r}")
    if fmt == "radiate":
        paths, stamps = radiate.radiate_sweeps(root)
        corrections = base = None
        if repair_stamps:
            base = fit_time_base(stamps, period_hint_us=radiate.RADIATE_SWEEP_PERIOD_S * 1e6)
            stamps, corrections = base.times_us, base.corrections_us
            if load_kwargs.get("sweep_period_s") is None:  # the azimuths spread over the fitted period too
                load_kwargs = {**load_kwargs, "sweep_period_s": base.period_s}
            if base.summary():
                warnings.warn(f"{root}: {base.summary()}; to keep them as recorded, read with repair_stamps=False "
                              "(radar-odom run --keep-stamps)",
                              StampWarning, stacklevel=2)
        return Sequence(root, fmt, paths, stamps, None, load_kwargs, corrections, base)
    paths, stamps = _sweep_files(folder)
    if format is not None and load_kwargs.get("range_resolution_m") is None:
        found = layout_evidence(paths[0])
        if found is not None:  # said once here; load_scan says it again per folder
            warn_format_contradiction(root, fmt, [found], stacklevel=3)
    gap_us = int(round(max_pose_gap_s * 1e6))
    if fmt == "oxford":
        paths, stamps = _reception_order(root, paths, stamps)
        rel = _oxford_gt(root, stamps)
    elif fmt == "boreas":
        rel = _zup_gt(root / boreas.POSES_RELPATH, boreas.read_boreas_poses, stamps, gap_us)
    else:
        period_s = load_kwargs.get("sweep_period_s")
        half = int(round((mulran.MULRAN_SWEEP_PERIOD_S if period_s is None else period_s) * 1e6 / 2))
        rel = _zup_gt(root / mulran.POSES_FILENAME, mulran.read_mulran_poses, stamps - half, gap_us)
    if rel is not None and (len(rel) == 0 or not np.isfinite(rel).all(axis=1).any()):
        rel = None  # a ground-truth file that covers none of these sweeps is no ground truth
    return Sequence(root, fmt, paths, stamps, rel, load_kwargs)
