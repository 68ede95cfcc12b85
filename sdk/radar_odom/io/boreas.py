"""Boreas (Navtech CIR204-H): sweep PNGs and ``applanix/radar_poses.csv``.

Sweeps use the Oxford row header (`._layout`) with three differences: column 10 is not a
validity flag (every row is used), the file name is the sweep's **middle** time (µs), and
ranges are ``bin · res − 0.31 m`` with ``res`` set by the recording date (see
`boreas_range_resolution_m`). Azimuths are the encoder angles of each row, which are
non-uniform in older sweeps; they are kept as they are.

Ground truth: ``applanix/radar_poses.csv`` holds absolute poses of the radar frame in ENU
(x east, y north, z up) at the radar timestamps: ``GPSTime`` (same clock and unit as the file
names), ``easting, northing, altitude``, and ``roll, pitch, heading`` where the rotation
ENU ← body is ``Rz(heading) · Ry(pitch) · Rx(roll)`` (heading = yaw about ENU z-up,
counter-clockwise from east, as the Boreas dev kit composes it; body x forward, y left, z up).
`read_sequence` turns these into Oxford relative poses (see `._zup`).
"""
from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..errors import SequenceError
from ..scan import RadarScan
from ._layout import (
    check_dims,
    name_timestamp,
    read_png_u8,
    scan_from_header_image,
    split_header,
    to_microseconds,
)
from ._zup import rotation_zyx

BOREAS_RANGE_OFFSET_M = -0.31
BOREAS_RES_BEFORE_M = 0.0596
BOREAS_RES_AFTER_M = 0.04381
# the radar was reconfigured on this date; UTC midnight (no sequence was recorded near it)
BOREAS_RES_CHANGE_US = int(datetime(2021, 9, 21, tzinfo=timezone.utc).timestamp()) * 1_000_000
POSES_RELPATH = Path("applanix") / "radar_poses.csv"
POSE_COLUMNS = ("GPSTime", "easting", "northing", "altitude", "roll", "pitch", "heading")


def boreas_range_resolution_m(timestamp_us: int) -> float:
    """Metres per bin of a Boreas sweep recorded at ``timestamp_us`` (UNIX µs).

    0.0596 m before 2021-09-21, 0.04381 m from then on.
    """
    return BOREAS_RES_BEFORE_M if timestamp_us < BOREAS_RES_CHANGE_US else BOREAS_RES_AFTER_M


def load_boreas(
    path, *, range_resolution_m=None, range_offset_m=None, num_azimuths=None, num_bins=None
) -> RadarScan:
    """Read one Boreas sweep PNG; resolution by date unless given, offset −0.31 m unless given."""
    img = read_png_u8(path)
    check_dims(img, str(path), header=True, num_azimuths=num_azimuths, num_bins=num_bins)
    if range_resolution_m is None:
        when = name_timestamp(path)
        if when is None:  # renamed file: the first azimuth's time tells the date just as well
            when = int(split_header(img).timestamps[0])
        range_resolution_m = boreas_range_resolution_m(int(to_microseconds(np.array([when]))[0]))
    return scan_from_header_image(
        img,
        str(path),
        use_valid_column=False,
        range_resolution_m=range_resolution_m,
        range_offset_m=BOREAS_RANGE_OFFSET_M if range_offset_m is None else range_offset_m,
    )


def read_boreas_poses(path) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_us int64[M], T_enu_body float64[M, 4, 4])`` from ``applanix/radar_poses.csv``."""
    from ._csv import read_numeric_csv

    names, stamps, values = read_numeric_csv(path, required=POSE_COLUMNS)
    col = {n: names.index(n) - 1 for n in POSE_COLUMNS[1:]}  # value columns follow the stamp
    if names[0] != "GPSTime":
        raise SequenceError(f"{path}: the first column must be GPSTime, got {names[0]!r}")
    t = np.zeros((len(stamps), 4, 4))
    t[:, :3, :3] = rotation_zyx(values[:, col["heading"]], values[:, col["pitch"]], values[:, col["roll"]])
    t[:, :3, 3] = values[:, [col["easting"], col["northing"], col["altitude"]]]
    t[:, 3, 3] = 1.0
    return to_microseconds(stamps), t
