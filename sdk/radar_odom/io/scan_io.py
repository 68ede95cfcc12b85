"""`load_scan`: one entry point for sweeps of every supported dataset, with format detection."""
from __future__ import annotations

import warnings
from pathlib import Path

from ..errors import FormatWarning
from ..scan import RadarScan
from .boreas import POSES_RELPATH, load_boreas
from .mulran import MULRAN_SWEEP_PERIOD_S, OXFORD_FORM_DIR, RAW_DIR, load_mulran
from .oxford import load_oxford
from .radiate import POLAR_DIR, load_radiate

FORMATS = ("oxford", "boreas", "mulran", "radiate")


def detect_format(path) -> str:
    """Dataset of a sweep file, from where it lies (the PNG alone cannot tell Oxford from Boreas).

    ``.../polar/*.png`` or ``.../polar_oxford_form/*.png`` → ``"mulran"``;
    ``.../Navtech_Polar/*.png`` → ``"radiate"``; ``SEQ/radar/*.png`` with ``SEQ/applanix/``
    beside it → ``"boreas"``; anything else → ``"oxford"``.
    """
    folder = Path(path).parent
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
    """
    fmt = detect_format(path) if format is None else format
    if format is not None and format in FORMATS and range_resolution_m is None:
        _check_format_against_layout(path, format)
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
    raise ValueError(f"unknown radar format {format!r}; choose one of {', '.join(FORMATS)} or None")


def _check_format_against_layout(path, format: str) -> None:
    """A `FormatWarning` where ``format`` contradicts a layout the folder names for certain: a MulRan or
    RADIATE folder, a Boreas sequence (``applanix/`` beside it). A bare folder proves nothing (the
    loaders check what the content can tell: MulRan's header stamps are ns, Oxford's and Boreas's µs)."""
    found = detect_format(path)
    if found != format and found != "oxford":  # "oxford" is detect_format's fallback, not a finding
        warnings.warn(
            f"{path}: read as {format!r} as asked, but its folder is laid out as {found!r}; the range "
            f"resolution is {format}'s default — pass range_resolution_m= if that is not this radar's, or "
            "leave format=None to detect it",
            FormatWarning, stacklevel=3)

