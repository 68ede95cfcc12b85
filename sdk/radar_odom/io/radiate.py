"""RADIATE (Sheeny et al., ICRA 2021; Navtech CTS350-X): polar sweeps and ``Navtech_Polar.txt``.

Layout on disk::

    SEQ/Navtech_Polar/NNNNNN.png    one sweep: uint8 [576 range rows, 400 azimuth columns]
    SEQ/Navtech_Polar.txt           "Frame: 000001 Time: 1574859771.744660272" per sweep

A sweep PNG is transposed against Oxford (rows = range bins, columns = azimuths) and has no
metadata columns: no per-azimuth timestamps, no encoder counts, no valid flags. Range bins are
0.173611 m apart, bin 0 at range 0 (``range_offset_m = 0``, the Oxford reader's and
`RadarScan`'s convention); 576 bins reach 100 m. The file name is the frame number; the time
file gives each frame's UNIX time in seconds (read exactly, to the µs; see `parse_frame_times`).

Time files (``Navtech_Polar.txt``, and ``GPS_IMU_Twist.txt`` read by `.gnss_ins`) as published:
some print the nanoseconds **without zero padding**, so ``Time: 1549986598.4512151`` means
1549986598 s + 4 512 151 ns (= …598.004512151 s), not …598.4512151 s
(``radiate-2019-02-12-edinburgh``); others print nine digits, where both readings agree
(``radiate-fog_6_0``). Which one a file means is decided per file: the reading under which
the times increase with the frame number, and, when both do, the one whose neighbouring
spacings are the more regular (a misread line stands out as a jump of up to ≈ 1 s).

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
from dataclasses import dataclass
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

_LINE = re.compile(r"^\s*Frame:\s*(\d+)\s+Time:\s*(\d+)(?:\.(\d*))?\s*$", re.ASCII)
# 12 digits of UNIX seconds reach the year 33658; more is a time in another unit (ns, µs)
# written without its decimal point, and would overflow int64 µs
_MAX_SECOND_DIGITS = 12
_NS_DIGITS = 9
DECIMAL = "decimal"  # the fraction is a decimal fraction of a second: ".45" = 0.45 s
NANOSECONDS = "nanoseconds"  # the fraction is whole nanoseconds, unpadded: ".45" = 45 ns
AGREE = "agree"  # every fraction has nine digits (or none): both readings give the same times
_READ_AS = {DECIMAL: "as decimals", NANOSECONDS: "as unpadded nanoseconds (RADIATE's other form)"}


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


def _nanoseconds_to_us(whole: str, frac: str | None) -> int:
    """Seconds and a fraction that counts whole nanoseconds (unpadded) → µs, rounded half up."""
    ns = int(frac or "0")
    return int(whole) * 1_000_000 + ns // 1000 + (1 if ns % 1000 >= 500 else 0)


@dataclass(frozen=True)
class FrameTimes:
    """The lines of a RADIATE ``FOLDER.txt`` time file, sorted by frame number.

    Attributes:
        frames: frame numbers, increasing.
        times_us: each frame's UNIX time in µs (exact integers), increasing (strictly for a
            sensor's frames; non-decreasing where the file lists a sample more than once).
        lines: the 1-based line of the file each frame was read from.
        reading: how the fractions were read: `DECIMAL`, `NANOSECONDS` or `AGREE`.
    """

    frames: tuple[int, ...]
    times_us: tuple[int, ...]
    lines: tuple[int, ...]
    reading: str


def _parse_lines(text: str, source: str) -> list[tuple[int, int, str, str]]:
    """``(line, frame, whole seconds, fraction digits)`` per non-blank line, in file order."""
    out = []
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
        if len(m.group(2).lstrip("0")) > _MAX_SECOND_DIGITS:
            raise SequenceError(
                f"{source}, line {lineno}: time {m.group(2)[:30]} is not UNIX seconds (more than "
                f"{_MAX_SECOND_DIGITS} digits before the point: ns or µs without a decimal point?); "
                "RADIATE time files give seconds, e.g. 'Time: 1574859771.744660272'"
            )
        out.append((lineno, int(m.group(1)), m.group(2), m.group(3) or ""))
    return out


def _times_us_as(entries, reading: str) -> list[int] | None:
    """Each entry's µs under ``reading``; None where the reading cannot apply (a fraction
    longer than nine digits is not a count of nanoseconds)."""
    if reading == DECIMAL:
        return [_seconds_to_us(whole, frac) for _, _, whole, frac in entries]
    if any(len(frac) > _NS_DIGITS for *_, frac in entries):
        return None
    return [_nanoseconds_to_us(whole, frac) for _, _, whole, frac in entries]


def _first_disorder(times_us: list[int], strictly: bool) -> int | None:
    """Index k of the first time not after (``strictly``) or before time k−1, else None."""
    for k in range(1, len(times_us)):
        if times_us[k] < times_us[k - 1] or (strictly and times_us[k] == times_us[k - 1]):
            return k
    return None


def _irregularity_us(times_us: list[int]) -> float:
    """Mean |spacing − median spacing| of neighbouring times, µs.

    A mean, not a median: a misread fraction shows as one or two odd spacings among many
    regular ones, and a median would not see them.
    """
    if len(times_us) < 3:
        return 0.0
    gaps = np.diff(np.array(times_us, dtype=np.float64))
    return float(np.mean(np.abs(gaps - np.median(gaps))))


def _disorder(entries, times_us: list[int], k: int, strictly: bool) -> str:
    """'line L: frame F at T s is not after frame F0 at T0 s (line L0)' for entry k."""
    (line0, frame0, *_), (line1, frame1, *_) = entries[k - 1], entries[k]
    relation = "is not after" if strictly else "is before"
    return (
        f"line {line1}: frame {frame1} at {times_us[k] / 1e6:.6f} s {relation} "
        f"frame {frame0} at {times_us[k - 1] / 1e6:.6f} s (line {line0})"
    )


def _steps_back(times_us: list[int]) -> int:
    """How many times are earlier than the time before them."""
    return sum(b < a for a, b in zip(times_us, times_us[1:]))


# with steps back allowed, a reading may go back at most this share of its steps: a receiver re-sync
# is one step in thousands, while unpadded nanoseconds read as decimals go back about once a second
MAX_STEP_BACK_SHARE = 0.01


def parse_frame_times(text: str, source: str, *, strictly_increasing: bool = True,
                      steps_back: bool = False) -> FrameTimes:
    """Read the ``Frame: N Time: S.F`` lines of a RADIATE time file (radar or GNSS/INS).

    The fraction F is read both as a decimal fraction of a second and as whole nanoseconds
    without zero padding (see the module docstring); the file's reading is the one under which
    the times increase with the frame number (strictly where ``strictly_increasing``; the
    GNSS/INS file lists each sample twice with the same time), the more regular one when both
    do, the decimal one when they tie.

    Args:
        text: the file's text; blank lines are ignored.
        source: the file's name, for messages.
        strictly_increasing: refuse equal times of neighbouring frames.
        steps_back: a clock that steps back now and then (a GNSS receiver's re-sync) is read on: the
            reading with the fewest steps back is taken, unless more than one and more than
            `MAX_STEP_BACK_SHARE` of its steps go back; the caller decides what to do with the overlap.

    Raises:
        SequenceError: naming ``source`` and the line, on a garbled line, a repeated frame
            number, an empty file, or times that do not increase under either reading.
    """
    entries = _parse_lines(text, source)
    if not entries:
        raise SequenceError(f"{source}: the time file lists no frames; re-copy it from the RADIATE release")
    first_line: dict[int, int] = {}
    for lineno, frame, *_ in entries:
        if frame in first_line:
            raise SequenceError(
                f"{source}, line {lineno}: frame {frame} is listed twice (first on line "
                f"{first_line[frame]}); keep one line per frame"
            )
        first_line[frame] = lineno
    entries.sort(key=lambda e: e[1])
    decimal = _times_us_as(entries, DECIMAL)
    nanos = _times_us_as(entries, NANOSECONDS)
    if nanos is None:
        readings = {DECIMAL: decimal}
    elif nanos == decimal:
        readings = {AGREE: decimal}
    else:
        readings = {DECIMAL: decimal, NANOSECONDS: nanos}
    disorder = {name: _first_disorder(us, strictly_increasing) for name, us in readings.items()}
    fits = [name for name, k in disorder.items() if k is None]
    if steps_back and not fits:
        back = {name: _steps_back(us) for name, us in readings.items()}
        fewest = min(back.values())
        if fewest <= max(1.0, MAX_STEP_BACK_SHARE * (len(entries) - 1)):
            fits = [name for name in readings if back[name] == fewest]
    if not fits:
        # lead with the reading that holds out longer: the file more likely means that one
        order = sorted(readings, key=lambda r: -disorder[r])  # stable: decimals first on a tie
        name = order[0]
        msg = f"{source}, " + _disorder(entries, readings[name], disorder[name], strictly_increasing)
        if len(order) == 2:
            other = order[1]
            msg += (
                f" with the fractions read {_READ_AS[name]}; read {_READ_AS[other]} the times fail too, "
                "at " + _disorder(entries, readings[other], disorder[other], strictly_increasing)
            )
        raise SequenceError(
            msg + "; times must increase with the frame number — the file is corrupt or its frames "
            "are renumbered"
        )
    # min keeps the first (decimal) of two equally regular readings
    reading = min(fits, key=lambda name: _irregularity_us(readings[name]))
    return FrameTimes(
        frames=tuple(e[1] for e in entries),
        times_us=tuple(readings[reading]),
        lines=tuple(e[0] for e in entries),
        reading=reading,
    )


def parse_radiate_times(text: str, source: str) -> dict[int, int]:
    """``{frame number: UNIX µs}`` from the text of a RADIATE sensor's ``FOLDER.txt`` time file.

    See `parse_frame_times` (times must increase strictly). Raises `SequenceError` naming
    ``source`` and the line on a garbled line, a repeated frame number, an empty file, or
    times that do not increase strictly with the frame number under either reading.
    """
    parsed = parse_frame_times(text, source, strictly_increasing=True)
    return dict(zip(parsed.frames, parsed.times_us))


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
