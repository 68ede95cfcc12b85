"""`load_scan`: one entry point for sweeps of every supported dataset, with format detection."""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import ConfigError, FormatWarning
from ..scan import RadarScan
from ._layout import name_timestamp, to_microseconds
from .boreas import POSES_RELPATH, load_boreas
from .mulran import MULRAN_SWEEP_PERIOD_S, OXFORD_FORM_DIR, RAW_DIR, load_mulran
from .oxford import GT_RELPATH, load_oxford
from .radiate import POLAR_DIR, load_radiate

FORMATS = ("oxford", "boreas", "mulran", "radiate")
# files only an Oxford recording keeps beside its radar/ folder (Boreas keeps applanix/ there)
OXFORD_SIDE_FILES = ("radar.timestamps", GT_RELPATH)
# range bins of the Oxford RobotCar radar (Navtech CTS350-X, 0.0432 m/bin, 163 m)
OXFORD_NUM_BINS = 3768


def sweep_path(path) -> Path:
    """``path`` as a `Path`: str, os.PathLike, or bytes (decoded as the file system does).

    Raises TypeError naming the type for anything else (None, a number, an open file, ...).
    """
    if not isinstance(path, (str, bytes, os.PathLike)):
        raise TypeError(f"a sweep path must be a file path (str, bytes or os.PathLike), got {type(path).__name__} "
                        f"{path!r:.60}")
    return Path(os.fsdecode(path))


def detect_format(path) -> str:
    """Dataset of a sweep file, from where it lies (the PNG alone cannot tell Oxford from Boreas).

    ``.../polar/*.png`` or ``.../polar_oxford_form/*.png`` → ``"mulran"``;
    ``.../Navtech_Polar/*.png`` → ``"radiate"``; ``SEQ/radar/*.png`` with ``SEQ/applanix/``
    beside it → ``"boreas"``; anything else → ``"oxford"``.
    """
    folder = sweep_path(path).parent
    if folder.name in (RAW_DIR, OXFORD_FORM_DIR):
        return "mulran"
    if folder.name == POLAR_DIR:
        return "radiate"
    if (folder.parent / POSES_RELPATH.parent).is_dir():
        return "boreas"
    return "oxford"


def load_scan(
    path,
    format: str | None = None,
    *,
    range_resolution_m: float | None = None,
    range_offset_m: float | None = None,
    num_azimuths: int | None = None,
    num_bins: int | None = None,
    sweep_period_s: float | None = None,
) -> RadarScan:
    """Read one radar sweep PNG into a `RadarScan`.

    Args:
        path: the PNG file.
        format: ``"oxford"``, ``"boreas"``, ``"mulran"``, ``"radiate"`` or None to detect it
            from the folder layout (`detect_format`).
        range_resolution_m: metres per bin; default per dataset (Oxford 0.0432, Boreas by
            date 0.0596 / 0.04381, MulRan 0.05952, RADIATE 0.173611).
        range_offset_m: range of bin 0; default 0 (Boreas −0.31).
        num_azimuths, num_bins: expected sweep size; a file of another size raises (RADIATE
            expects 400 × 576 unless told otherwise).
        sweep_period_s: sweeps without per-azimuth times only: the time their azimuths span.
            MulRan raw: before the end-of-sweep time in the file name (default 0.25 s);
            RADIATE: after the frame time (default: the median frame spacing in
            ``Navtech_Polar.txt``).

    Raises:
        ScanFormatError: missing, empty, non-PNG or truncated file; not 8-bit greyscale; wrong
            size; encoder counts not increasing; every row invalid; RADIATE: no usable time for
            the frame in ``Navtech_Polar.txt``.
        TypeError: ``path`` is not a path (None, a number, ...).

    Warns:
        FormatWarning: an explicit ``format`` (without ``range_resolution_m``) that the folder
            layout (`layout_evidence`) or, where the folder says nothing, an Oxford or Boreas sweep's
            own name and width (`content_evidence`) contradict; the sweep is read as asked. The
            message names the folder, not the file: a recording read with the wrong format gives one
            line under Python's default warning filter, not one per sweep.
    """
    path = sweep_path(path)
    fmt = detect_format(path) if format is None else format
    check = format is not None and format in FORMATS and range_resolution_m is None
    layout = layout_evidence(path) if check else None  # once per sweep: it looks at the file system
    if layout is not None:
        warn_format_contradiction(path.parent, format, [layout])
    scan = _load(path, fmt, range_resolution_m=range_resolution_m, range_offset_m=range_offset_m,
                 num_azimuths=num_azimuths, num_bins=num_bins, sweep_period_s=sweep_period_s)
    if check and layout is None and format in ("oxford", "boreas"):
        warn_format_contradiction(path.parent, format, content_evidence(path, scan))
    return scan


def _load(path: Path, fmt, *, range_resolution_m, range_offset_m, num_azimuths, num_bins, sweep_period_s) -> RadarScan:
    if fmt == "oxford":
        return load_oxford(
            path,
            range_resolution_m=range_resolution_m,
            range_offset_m=range_offset_m,
            num_azimuths=num_azimuths,
            num_bins=num_bins,
        )
    if fmt == "boreas":
        return load_boreas(
            path,
            range_resolution_m=range_resolution_m,
            range_offset_m=range_offset_m,
            num_azimuths=num_azimuths,
            num_bins=num_bins,
        )
    if fmt == "mulran":
        return load_mulran(
            path,
            range_resolution_m=range_resolution_m,
            range_offset_m=range_offset_m,
            num_azimuths=num_azimuths,
            num_bins=num_bins,
            sweep_period_s=MULRAN_SWEEP_PERIOD_S if sweep_period_s is None else sweep_period_s,
        )
    if fmt == "radiate":
        return load_radiate(
            path,
            range_resolution_m=range_resolution_m,
            range_offset_m=range_offset_m,
            num_azimuths=num_azimuths,
            num_bins=num_bins,
            sweep_period_s=sweep_period_s,
        )
    raise ConfigError(f"unknown radar format {fmt!r}; choose one of {', '.join(FORMATS)} or None")


def layout_evidence(path) -> tuple[str, str] | None:
    """(format, why) where the folder around a sweep names its dataset for certain, else None.

    A MulRan or RADIATE folder, a Boreas sequence (``applanix/`` beside ``radar/``), an Oxford one
    (``radar.timestamps`` or ``gt/radar_odometry.csv`` beside ``radar/``). A bare folder proves nothing.
    """
    path = Path(path)
    found = detect_format(path)
    if found != "oxford":  # "oxford" is detect_format's fallback, not a finding
        return found, f"its folder is laid out as {found!r}"
    folder = path.parent
    if folder.name == "radar":
        for rel in OXFORD_SIDE_FILES:
            if (folder.parent / rel).exists():
                return "oxford", (f"its folder is laid out as 'oxford' ({Path(rel).as_posix()} lies beside radar/, "
                                  "as in Oxford recordings)")
    return None


def content_evidence(path, scan: RadarScan) -> list[tuple[str, str]]:
    """(format, why) pairs that an Oxford-layout sweep's own content tells of its dataset.

    The file name: Oxford names a sweep by its first azimuth's time, Boreas by its middle time
    (told apart only where the valid rows span time, by a margin of a tenth of the span). The
    width: 3768 range bins is the Oxford RobotCar radar's.
    """
    found = []
    name = name_timestamp(path)
    ts = np.asarray(scan.timestamps_us)[np.asarray(scan.valid)]
    if name is not None and ts.size >= 2 and ts[-1] > ts[0]:
        name_us = int(to_microseconds(np.array([name]))[0])
        first, span = int(ts[0]), int(ts[-1]) - int(ts[0])
        mid = first + span / 2
        near, far = span / 10, span / 3
        if abs(name_us - first) <= near and abs(name_us - mid) >= far:
            found.append(("oxford", "its file name is its first azimuth's time, as Oxford names sweeps (Boreas "
                                    "names the middle)"))
        elif abs(name_us - mid) <= near and abs(name_us - first) >= far:
            found.append(("boreas", "its file name is its middle azimuth's time, as Boreas names sweeps (Oxford "
                                    "names the first)"))
    if scan.num_bins == OXFORD_NUM_BINS:
        found.append(("oxford", f"it has {OXFORD_NUM_BINS} range bins, as the Oxford RobotCar radar writes"))
    return found


def warn_format_contradiction(where, format: str, reasons: list[tuple[str, str]], stacklevel: int = 3) -> None:
    """A `FormatWarning` at ``where`` (a folder) for the ``reasons`` (format, why) that name another
    format than the ``format`` asked for; nothing where none does. ``stacklevel`` 3: the caller of
    the caller (`load_scan`'s)."""
    others = [(f, why) for f, why in reasons if f != format]
    if not others:
        return
    said = "; ".join(why for _, why in others)
    warnings.warn(
        f"{where}: sweeps read as {format!r} as asked, but {said}; the range resolution and offset are {format}'s "
        "defaults — leave format=None to detect it, or pass range_resolution_m= if it is this radar's",
        FormatWarning, stacklevel=stacklevel)
