"""RADIATE (Sheeny et al., ICRA 2021; Navtech CTS350-X): polar sweeps and ``Navtech_Polar.txt``.

Layout on disk::

    SEQ/Navtech_Polar/NNNNNN.png    one sweep: uint8 [576 range rows, 400 azimuth columns]
    SEQ/Navtech_Polar.txt           "Frame: 000001 Time: 1574859771.744660272" per sweep

A sweep PNG is transposed against Oxford (rows = range bins, columns = azimuths) and has no
metadata columns: no per-azimuth timestamps, no encoder counts, no valid flags. Range bins are
0.173611 m apart, bin 0 at range 0 (``range_offset_m = 0``, the Oxford reader's and
`RadarScan`'s convention); 576 bins reach 100 m. The file name is the frame number; the time
file gives each frame's UNIX time in seconds (read exactly, to the µs).

What this reader assumes, and why:

- **Azimuths** are uniform over the turn, column ``a`` at ``2π·a/A`` (A = 400), and follow our
  Oxford convention: azimuth 0 along +x (forward), growing towards +y (right, i.e. clockwise
  seen from above). The RADIATE SDK (github.com/marcelsheeny/radiate_sdk) says only that the
  polar image is "400 x 576 (azimuth x range)", that "index 0 from the azimuth axis represents
  the angle 0° and 399 represents the angle 360°" and that the range index 0 is 0 m and 575
  is 100 m (README.md, *radar_polar*); ``config/config.yaml`` gives ``range_res: 0.173611``,
  ``range_cells: 576``, ``azimuth_cells: 400``. The SDK holds no polar→Cartesian code
  (``radiate.py`` reads the released ``Navtech_Cartesian`` PNGs) and states neither the
  direction of rotation nor where azimuth 0 points. The columns are the sensor's own output in
  encoder order ("the raw polar format provided by the sensor manufacturer"), from the same
  CTS350-X as Oxford, whose encoder angle grows clockwise from the front; third-party RADIATE
  loaders read the columns the same way (column 0 forward, growing clockwise). On the shared
  real sweeps (fog_6_0), consecutive sweeps read this way correlate best at a shift along +x,
  as a car driving forward gives, so azimuth 0 does point forward; the direction of rotation
  cannot be checked there (no usable IMU), so it rests on the sensor's convention.
- **Times**: a frame's time is taken as its first azimuth's, and the azimuth times are spread
  uniformly over one sweep period after it: ``t[a] = t_frame + round(a · period / A)``. The
  period is the median spacing of neighbouring frame times in ``Navtech_Polar.txt`` (≈ 0.25 s at
  4 Hz), unless ``sweep_period_s`` is given. The RADIATE README calls each sensor's timestamp
  its data's "time of arrival" without naming an azimuth; if that is the end of the sweep, every
  time here is early by the same ≤ one period, which leaves relative poses unchanged.
"""
from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np

from ..errors import ScanFormatError, SequenceError
from ..scan import RadarScan
from ._layout import check_dims, read_png_u8

RADIATE_RANGE_RESOLUTION_M = 0.173611
RADIATE_NUM_AZIMUTHS = 400
RADIATE_NUM_BINS = 576
# used only when the time file holds a single frame, so no spacing can be measured
RADIATE_SWEEP_PERIOD_S = 0.25
POLAR_DIR = "Navtech_Polar"
TIMES_FILENAME = POLAR_DIR + ".txt"

_LINE = re.compile(r"^\s*Frame:\s*(\d+)\s+Time:\s*(\d+)(?:\.(\d*))?\s*$")


def times_path(sweep_path) -> Path:
    """``SEQ/Navtech_Polar.txt`` for a sweep ``SEQ/Navtech_Polar/NNNNNN.png``."""
    folder = Path(sweep_path).parent
    return folder.parent / (folder.name + ".txt")


def frame_number(path) -> int | None:
    """The frame number a sweep's file name holds (``000017.png`` → 17), or None."""
    stem = Path(path).stem
    return int(stem) if stem.isascii() and stem.isdigit() else None


def _seconds_to_us(whole: str, frac: str | None) -> int:
    """Decimal seconds as written → µs, rounded half up, exactly (float64 keeps ~0.2 µs at 1.6e9 s)."""
    frac = frac or ""
    us = int(whole) * 1_000_000 + int((frac + "000000")[:6])
    return us + (1 if len(frac) > 6 and frac[6] >= "5" else 0)


def parse_radiate_times(text: str, source: str) -> dict[int, int]:
    """``{frame number: UNIX µs}`` from the text of a RADIATE ``FOLDER.txt`` time file.

    Raises `SequenceError` naming ``source`` and the line on a garbled line, a repeated frame
    number, an empty file, or times that do not increase strictly with the frame number.
    """
    times: dict[int, int] = {}
    lines: dict[int, int] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _LINE.match(line)
        if m is None:
            raise SequenceError(
                f"{source}, line {lineno}: cannot read {line.strip()[:60]!r}; expected "
                "'Frame: NNNNNN Time: SECONDS' (e.g. 'Frame: 000001 Time: 1574859771.744660272'); "
                "the file is truncated or edited — re-copy it from the RADIATE release"
            )
        frame = int(m.group(1))
        if frame in times:
            raise SequenceError(
                f"{source}, line {lineno}: frame {frame} is listed twice (first on line "
                f"{lines[frame]}); keep one line per frame"
            )
        times[frame] = _seconds_to_us(m.group(2), m.group(3))
        lines[frame] = lineno
    if not times:
        raise SequenceError(f"{source}: the time file lists no frames; re-copy it from the RADIATE release")
    frames = sorted(times)
    for prev, cur in zip(frames[:-1], frames[1:]):
        if times[cur] <= times[prev]:
            raise SequenceError(
                f"{source}, line {lines[cur]}: frame {cur} at {times[cur] / 1e6:.6f} s is not after "
                f"frame {prev} at {times[prev] / 1e6:.6f} s (line {lines[prev]}); times must increase "
                "with the frame number — the file is corrupt or its frames are renumbered"
            )
    return times


@functools.lru_cache(maxsize=8)
def _cached_times(path: str, mtime_ns: int, size: int) -> dict[int, int]:
    # keyed by modification time and size too, so an edited file is read again
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{p}: cannot read the RADIATE time file ({exc})") from None
    return parse_radiate_times(text, str(p))


def read_radiate_times(path) -> dict[int, int]:
    """``{frame number: UNIX µs}`` from ``SEQ/Navtech_Polar.txt`` (see `parse_radiate_times`).

    Parsed once per file version (a small cache keyed by path, size and modification time), so
    a sequence's sweeps do not re-read it. Do not modify the returned dict.
    """
    p = Path(path)
    if not p.is_file():
        raise SequenceError(
            f"{p}: no such file; RADIATE sweeps carry no timestamps, so SEQ/{TIMES_FILENAME} "
            "must lie beside the Navtech_Polar/ folder"
        )
    st = p.stat()
    return _cached_times(str(p.resolve()), st.st_mtime_ns, st.st_size)


def sweep_period_us(times: dict[int, int]) -> float:
    """One sweep's duration in µs: the median spacing of neighbouring frames' times.

    Neighbours are consecutive frame numbers (a frame missing from the file does not make a
    double-length gap count); with no such pair the default 0.25 s (4 Hz) is used.
    """
    frames = np.array(sorted(times), dtype=np.int64)
    stamps = np.array([times[f] for f in frames.tolist()], dtype=np.int64)
    adjacent = np.diff(frames) == 1
    if not adjacent.any():
        return RADIATE_SWEEP_PERIOD_S * 1e6
    return float(np.median(np.diff(stamps)[adjacent]))


def azimuth_times_us(start_us: int, num_azimuths: int, period_us: float) -> np.ndarray:
    """int64[A]: the first at ``start_us``, then one ``period_us / A`` step per azimuth."""
    return start_us + np.round(np.arange(num_azimuths) * (period_us / num_azimuths)).astype(np.int64)


def _check_shape(img: np.ndarray, source: str, num_azimuths: int, num_bins: int) -> None:
    """`ScanFormatError` unless ``img`` is [num_bins rows, num_azimuths columns]."""
    if img.shape == (num_bins, num_azimuths):
        return
    if img.shape == (num_azimuths, num_bins):
        raise ScanFormatError(
            f"{source}: image is {img.shape[0]} × {img.shape[1]} (rows × columns), the transpose of a "
            f"RADIATE sweep ({num_bins} range rows × {num_azimuths} azimuth columns); it was saved "
            "azimuth-major — transpose it back, or read it with the format it was written in"
        )
    raise ScanFormatError(
        f"{source}: image is {img.shape[0]} × {img.shape[1]} (rows × columns), expected a RADIATE "
        f"sweep of {num_bins} range rows × {num_azimuths} azimuth columns; is this a Navtech_Polar "
        "PNG? (for another size pass num_bins= / num_azimuths=)"
    )


def load_radiate(
    path,
    *,
    range_resolution_m: float | None = None,
    range_offset_m: float | None = None,
    num_azimuths: int | None = None,
    num_bins: int | None = None,
    sweep_period_s: float | None = None,
    timestamp_us: int | None = None,
) -> RadarScan:
    """Read one RADIATE sweep ``SEQ/Navtech_Polar/NNNNNN.png`` into a `RadarScan`.

    Args:
        path: the PNG, uint8 [B range rows, A azimuth columns] (576 × 400 in the release).
        range_resolution_m: metres per bin; default 0.173611.
        range_offset_m: range of bin 0; default 0.
        num_azimuths, num_bins: expected size; default RADIATE's 400 and 576.
        sweep_period_s: time spanned by the azimuths; default the median spacing of neighbouring
            frames in ``SEQ/Navtech_Polar.txt``.
        timestamp_us: the first azimuth's UNIX µs; default the frame's time in
            ``SEQ/Navtech_Polar.txt``. Only a sweep given both this and ``sweep_period_s`` is
            read without the time file.

    Returns:
        power float32[A, B] (``img.T / 255``), azimuths ``2π·a/A``, every row valid, timestamps
        spread over one period from the frame time (see the module docstring).

    Raises:
        ScanFormatError: bad PNG (see `load_scan`), wrong size, or no usable time for the frame
            (time file missing or garbled, frame not listed, times not increasing).
    """
    path = Path(path)
    src = str(path)
    img = read_png_u8(path)
    a_want = RADIATE_NUM_AZIMUTHS if num_azimuths is None else int(num_azimuths)
    b_want = RADIATE_NUM_BINS if num_bins is None else int(num_bins)
    _check_shape(img, src, a_want, b_want)
    check_dims(img, src, header=False)  # at least 2 × 2
    res = RADIATE_RANGE_RESOLUTION_M if range_resolution_m is None else range_resolution_m
    offset = 0.0 if range_offset_m is None else range_offset_m
    period_us = None if sweep_period_s is None else float(sweep_period_s) * 1e6
    if timestamp_us is None or period_us is None:
        times = _times_for(path)
        if timestamp_us is None:
            frame = frame_number(path)
            if frame is None:
                raise ScanFormatError(
                    f"{src}: RADIATE sweep names are frame numbers (e.g. 000001.png), so its time "
                    f"in {TIMES_FILENAME} cannot be found; rename it or pass timestamp_us="
                )
            if frame not in times:
                raise ScanFormatError(
                    f"{src}: frame {frame} has no line in {times_path(path)}; the time file is "
                    "truncated or belongs to another sequence — re-copy it, or pass timestamp_us="
                )
            timestamp_us = times[frame]
        if period_us is None:
            period_us = sweep_period_us(times)
    power = img.T  # rows = azimuths, as RadarScan wants
    a = power.shape[0]
    return RadarScan.from_arrays(
        azimuth_times_us(int(timestamp_us), a, period_us),
        np.arange(a) * (2.0 * np.pi / a),
        power,
        range_resolution_m=res,
        range_offset_m=offset,
        source=src,
    )


def _times_for(path: Path) -> dict[int, int]:
    """The time file of a sweep, its problems as `ScanFormatError` naming the sweep."""
    try:
        return read_radiate_times(times_path(path))
    except SequenceError as exc:
        raise ScanFormatError(f"{path}: cannot time the sweep: {exc}") from None


def radiate_sweeps(root) -> tuple[list[Path], np.ndarray]:
    """Sweep PNGs of a RADIATE sequence in frame order and their frame times (int64 µs).

    Raises `SequenceError` when ``SEQ/Navtech_Polar/`` holds no PNG, a name is not a frame
    number, or ``SEQ/Navtech_Polar.txt`` is missing, garbled, not increasing or lacks a frame.
    """
    root = Path(root)
    folder = root / POLAR_DIR
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".png" and p.is_file()]
    if not files:
        raise SequenceError(f"{folder}: holds no radar PNGs")
    bad = sorted(p.name for p in files if frame_number(p) is None)
    if bad:
        raise SequenceError(
            f"{folder}: RADIATE sweep names must be frame numbers (e.g. 000001.png), got "
            f"{', '.join(bad[:3])}"
        )
    files.sort(key=frame_number)
    times = read_radiate_times(root / TIMES_FILENAME)
    missing = [p.name for p in files if frame_number(p) not in times]
    if missing:
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise SequenceError(
            f"{root / TIMES_FILENAME}: no line for {', '.join(missing[:3])}{more}; the time file is "
            "truncated or belongs to another sequence — re-copy it from the RADIATE release"
        )
    return files, np.array([times[frame_number(p)] for p in files], dtype=np.int64)
