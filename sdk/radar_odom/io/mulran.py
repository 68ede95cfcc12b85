"""MulRan (Navtech CIR204-H): raw polar PNGs, their Oxford-form copies, and ``global_pose.csv``.

Two sweep layouts, both named ``<end-of-sweep time in ns>.png``:

- ``polar/``: raw power with **no header**, transposed (rows = 3360 range bins at 0.05952 m,
  columns = azimuths). Azimuths are taken as uniform (``a · 2π / A``) and the azimuth times as
  spread evenly over the ``sweep_period_s`` (0.25 s) before the name's time, the last azimuth
  at the name's time.
- ``polar_oxford_form/``: the Oxford layout (`._layout`) with ns timestamps in the header
  (converted to µs).

Ground truth ``global_pose.csv``: per line ``stamp_ns`` then the row-major 3×4 ``[R|t]`` of the
body (x forward, y left, z up) in a z-up world frame; a header line is allowed.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import FormatWarning, ScanFormatError
from ..scan import RadarScan
from ._layout import (
    NS_THRESHOLD,
    check_dims,
    looks_like_header,
    name_timestamp,
    read_png_u8,
    scan_from_header_image,
    split_header,
    to_microseconds,
)

MULRAN_RANGE_RESOLUTION_M = 0.05952
MULRAN_SWEEP_PERIOD_S = 0.25
POSES_FILENAME = "global_pose.csv"
RAW_DIR, OXFORD_FORM_DIR = "polar", "polar_oxford_form"


def raw_azimuth_times_us(end_us: int, num_azimuths: int, sweep_period_s: float) -> np.ndarray:
    """int64[A] azimuth times: evenly spaced, the last at ``end_us``, spanning one period."""
    step_us = sweep_period_s * 1e6 / num_azimuths
    back = (num_azimuths - 1 - np.arange(num_azimuths)) * step_us
    return end_us - np.round(back).astype(np.int64)


def load_mulran(
    path,
    *,
    range_resolution_m=None,
    range_offset_m=None,
    num_azimuths=None,
    num_bins=None,
    sweep_period_s: float = MULRAN_SWEEP_PERIOD_S,
) -> RadarScan:
    """Read a MulRan sweep, raw transposed or Oxford-form (told apart by folder name, else content)."""
    path = Path(path)
    src = str(path)
    img = read_png_u8(path)
    res = MULRAN_RANGE_RESOLUTION_M if range_resolution_m is None else range_resolution_m
    offset = 0.0 if range_offset_m is None else range_offset_m
    folder = path.parent.name
    oxford_form = folder == OXFORD_FORM_DIR or (folder != RAW_DIR and looks_like_header(img))
    if oxford_form:
        check_dims(img, src, header=True, num_azimuths=num_azimuths, num_bins=num_bins)
        stamps = split_header(img).timestamps
        if range_resolution_m is None and stamps.size and int(stamps.max()) < NS_THRESHOLD:
            # MulRan writes ns into the header; µs is Oxford's and Boreas's layout (0.0432 / 0.0596 m bins)
            warnings.warn(f"{src}: read as 'mulran' as asked, but its header holds µs timestamps, as Oxford and "
                          "Boreas sweeps do (MulRan's hold ns); the range resolution is MulRan's "
                          f"{MULRAN_RANGE_RESOLUTION_M} m — pass range_resolution_m= or the right format",
                          FormatWarning, stacklevel=3)
        return scan_from_header_image(
            img, src, use_valid_column=True, range_resolution_m=res, range_offset_m=offset
        )
    check_dims(img, src, header=False, num_azimuths=num_azimuths, num_bins=num_bins)
    end = name_timestamp(path)
    if end is None:
        raise ScanFormatError(
            f"{src}: raw MulRan sweeps carry no timestamps, so the file name must be the "
            "end-of-sweep time in ns (e.g. 1566535954883011000.png)"
        )
    end_us = int(to_microseconds(np.array([end]))[0])
    power = img.T  # rows = azimuths, as RadarScan wants
    a = power.shape[0]
    return RadarScan.from_arrays(
        raw_azimuth_times_us(end_us, a, sweep_period_s),
        np.arange(a) * (2.0 * np.pi / a),
        power,
        range_resolution_m=res,
        range_offset_m=offset,
        source=src,
    )


def read_mulran_poses(path) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_us int64[M], T_world_body float64[M, 4, 4])`` from ``global_pose.csv``."""
    from ._csv import read_numeric_csv

    _, stamps, values = read_numeric_csv(path, num_columns=13)
    t = np.zeros((len(stamps), 4, 4))
    t[:, :3, :] = values.reshape(-1, 3, 4)
    t[:, 3, 3] = 1.0
    return to_microseconds(stamps), t
