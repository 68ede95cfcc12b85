"""PNG decoding with typed errors, and the 11-byte row header of the Oxford layout.

The Oxford layout (also used by Boreas and by MulRan's ``polar_oxford_form`` copies) stores one
sweep as an 8-bit greyscale PNG of ``A × (11 + B)`` pixels, one row per azimuth:

=========  ==================  ==============================================
columns    type                meaning
=========  ==================  ==============================================
0–7        int64 little-end.   timestamp of the azimuth (UNIX µs; MulRan: ns)
8–9        uint16 little-end.  encoder count, angle = count / 5600 · 2π
10         uint8               255 = valid azimuth (Boreas: unused)
11–        uint8               B range bins, power = value / 255
=========  ==================  ==============================================
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from ..errors import ScanFormatError
from ..scan import OXFORD_ENCODER_SIZE, RadarScan

HEADER_BYTES = 11
VALID_BYTE = 255
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# UNIX time is ~1.7e15 in µs and ~1.7e18 in ns; 1e17 µs would be the year 5138, so any
# timestamp above it must be in nanoseconds.
NS_THRESHOLD = 10**17


class HeaderRows(NamedTuple):
    """The Oxford-layout PNG split into its columns (each [A] or [A, B], copies)."""

    timestamps: np.ndarray  # int64[A], as stored (µs, or ns for MulRan)
    counts: np.ndarray  # uint16[A], encoder counts
    valid_byte: np.ndarray  # uint8[A], 255 = valid
    power_u8: np.ndarray  # uint8[A, B]


# Decompression bombs: a PNG of a few kB may declare billions of pixels. Its size is read from the
# IHDR chunk (the first 33 bytes) and refused before anything is decoded. The largest real sweep
# PNGs are a few million pixels (Oxford 400 × 3779, MulRan 3360 × 400); 2**25 pixels is a
# 5600-azimuth sweep of 5600 bins, and at most 64 MiB decoded.
MAX_PNG_PIXELS = 2**25
MAX_PNG_DECODED_BYTES = 2**26
IHDR_BYTES = 33  # signature (8) + length (4) + "IHDR" (4) + 13 data bytes + CRC (4)
# bytes per pixel OpenCV decodes each PNG colour type to (IMREAD_UNCHANGED; palette → BGR(A))
_DECODED_CHANNELS = {0: 1, 2: 3, 3: 4, 4: 4, 6: 4}


class PngHeader(NamedTuple):
    width: int
    height: int
    bit_depth: int
    colour_type: int


def read_png_header(path: Path, head: bytes) -> PngHeader:
    """Width, height, bit depth and colour type from a PNG's first 33 bytes, or `ScanFormatError`.

    Refuses (before any decoding) an image larger than `MAX_PNG_PIXELS` or one that would decode
    to more than `MAX_PNG_DECODED_BYTES`.
    """
    if len(head) < IHDR_BYTES:
        raise ScanFormatError(
            f"{path}: PNG is truncated ({len(head)} bytes, shorter than its header); re-copy it"
        )
    length = int.from_bytes(head[8:12], "big")
    if head[12:16] != b"IHDR" or length != 13:
        raise ScanFormatError(
            f"{path}: PNG is corrupt (its first chunk is not a 13-byte IHDR header); re-copy it"
        )
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    depth, colour = head[24], head[25]
    if width == 0 or height == 0 or colour not in _DECODED_CHANNELS or depth not in (1, 2, 4, 8, 16):
        raise ScanFormatError(
            f"{path}: PNG header is corrupt ({width} × {height} pixels, bit depth {depth}, colour type "
            f"{colour}); re-copy it"
        )
    pixels = width * height
    decoded = pixels * _DECODED_CHANNELS[colour] * (2 if depth == 16 else 1)
    if pixels > MAX_PNG_PIXELS or decoded > MAX_PNG_DECODED_BYTES:
        raise ScanFormatError(
            f"{path}: PNG declares {width} × {height} pixels ({decoded / 2**20:.0f} MiB decoded), more "
            f"than any radar sweep (at most {MAX_PNG_PIXELS} pixels, {MAX_PNG_DECODED_BYTES // 2**20} MiB); "
            "refused without decoding — the file is corrupt or not a radar sweep"
        )
    return PngHeader(width, height, depth, colour)


def read_png_u8(path: Path) -> np.ndarray:
    """Decode an 8-bit single-channel PNG to uint8[H, W], or raise `ScanFormatError`.

    The size in the PNG header is checked first (`read_png_header`): a decompression bomb is
    refused after reading 33 bytes.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanFormatError(f"{path}: no such file")
    try:
        with open(path, "rb") as f:
            head = f.read(IHDR_BYTES)
    except OSError as exc:
        raise ScanFormatError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if len(head) == 0:
        raise ScanFormatError(f"{path}: file is empty; re-copy the sweep")
    if head[: len(PNG_SIGNATURE)] != PNG_SIGNATURE:
        raise ScanFormatError(
            f"{path}: not a PNG file (starts with {head[:8]!r}); radar sweeps are 8-bit greyscale PNGs"
        )
    header = read_png_header(path, head)
    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except (cv2.error, MemoryError) as exc:
        raise ScanFormatError(
            f"{path}: PNG could not be decoded ({type(exc).__name__}); the file is corrupt; re-copy it"
        ) from None
    if img is None:
        raise ScanFormatError(
            f"{path}: PNG could not be decoded ({path.stat().st_size} bytes): the file is "
            "truncated or corrupt; re-copy it"
        )
    if img.shape[:2] != (header.height, header.width):  # changed under us, or a decoder surprise
        raise ScanFormatError(
            f"{path}: decoded {img.shape[1]} × {img.shape[0]} pixels but the header says "
            f"{header.width} × {header.height}; the file is corrupt"
        )
    if img.ndim != 2:
        raise ScanFormatError(
            f"{path}: expected a single-channel (greyscale) PNG, got {img.shape[2]} channels"
        )
    if img.dtype != np.uint8:
        bits = 8 * img.dtype.itemsize
        raise ScanFormatError(
            f"{path}: expected an 8-bit PNG, got a {bits}-bit one ({img.dtype}); radar sweeps "
            "store one byte per pixel"
        )
    return img


def check_dims(img: np.ndarray, source: str, *, header: bool, num_azimuths=None, num_bins=None) -> None:
    """Raise `ScanFormatError` if an Oxford-layout (``header``) or headerless image has the wrong size.

    Headerless images are the transposed MulRan layout: rows = bins, columns = azimuths.
    ``num_azimuths`` / ``num_bins`` are expectations (None: anything of at least 2).
    """
    h, w = img.shape
    if header:
        azimuths, bins, what_a, what_b = h, w - HEADER_BYTES, "height", "width"
        if bins < 2:
            raise ScanFormatError(
                f"{source}: width must be 11 header bytes + bins (at least 13), got {w}; "
                "is this an Oxford-layout radar PNG?"
            )
    else:
        azimuths, bins, what_a, what_b = w, h, "width", "height"
    if azimuths < 2:
        raise ScanFormatError(f"{source}: {what_a} must be the azimuth count (at least 2), got {azimuths}")
    if num_azimuths is not None and azimuths != num_azimuths:
        raise ScanFormatError(
            f"{source}: {what_a} must equal the azimuth count: expected {num_azimuths}, got {azimuths}"
        )
    if num_bins is not None and bins != num_bins:
        got = w if header else h
        want = num_bins + HEADER_BYTES if header else num_bins
        rule = f"11 + bins = {want}" if header else f"bins = {want}"
        raise ScanFormatError(f"{source}: {what_b} must be {rule} for {num_bins} bins, got {got}")


def split_header(img: np.ndarray) -> HeaderRows:
    """Columns of an Oxford-layout uint8[A, 11 + B] image (little-endian integers)."""
    ts = np.ascontiguousarray(img[:, 0:8]).view("<i8")[:, 0].astype(np.int64)
    counts = np.ascontiguousarray(img[:, 8:10]).view("<u2")[:, 0].astype(np.uint16)
    return HeaderRows(ts, counts, img[:, 10].copy(), img[:, HEADER_BYTES:].copy())


def join_header(timestamps, counts, valid_byte, power_u8) -> np.ndarray:
    """Inverse of `split_header`: uint8[A, 11 + B] from the four columns."""
    a = power_u8.shape[0]
    out = np.empty((a, HEADER_BYTES + power_u8.shape[1]), dtype=np.uint8)
    out[:, 0:8] = np.asarray(timestamps, dtype="<i8").reshape(a, 1).view(np.uint8)
    out[:, 8:10] = np.asarray(counts, dtype="<u2").reshape(a, 1).view(np.uint8)
    out[:, 10] = valid_byte
    out[:, HEADER_BYTES:] = power_u8
    return out


def looks_like_header(img: np.ndarray) -> bool:
    """Whether an image plausibly carries the Oxford row header (vs. raw headerless power).

    Raw power bytes read as int64 almost never give non-decreasing UNIX-time values with a
    0/255 flag column, so this tells MulRan's two layouts apart without a folder name.
    """
    if img.shape[1] < HEADER_BYTES + 2:
        return False
    rows = split_header(img)
    ok = rows.valid_byte == VALID_BYTE
    if not np.all((rows.valid_byte == 0) | ok) or not ok.any():
        return False
    ts = rows.timestamps[ok]
    return bool(np.all((ts > 10**14) & (ts < 10**20)) and np.all(np.diff(ts) >= 0))


def to_microseconds(values: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """int64 µs from integer timestamps in µs or ns (told apart by magnitude, see NS_THRESHOLD).

    ``reference`` (bool mask) picks the entries that decide the unit (e.g. valid rows only,
    whose timestamps are trustworthy). ns are floored to µs.
    """
    values = np.asarray(values, dtype=np.int64)
    ref = values if reference is None else values[reference]
    if ref.size and np.median(np.abs(ref)) > NS_THRESHOLD:
        return values // 1000
    return values


def name_timestamp(path: Path) -> int | None:
    """The integer a sweep's file name holds (µs or ns), or None if the stem is not an integer."""
    stem = Path(path).stem
    return int(stem) if stem.isascii() and stem.isdigit() else None


def check_counts_increasing(counts: np.ndarray, valid: np.ndarray, source: str) -> None:
    """Raise `ScanFormatError` unless encoder counts of valid rows increase strictly.

    Invalid rows are skipped: the sensor marks them invalid because their header is unreliable.
    """
    idx = np.flatnonzero(valid)
    c = counts[idx].astype(np.int64)
    bad = np.flatnonzero(np.diff(c) <= 0)
    if bad.size:
        i, j = idx[bad[0]], idx[bad[0] + 1]
        raise ScanFormatError(
            f"{source}: encoder counts must increase along the rows, but row {j} has "
            f"{int(counts[j])} after {int(counts[i])} in row {i}; the file is corrupt or its rows "
            "are out of order"
        )
    if c.size and c[-1] >= OXFORD_ENCODER_SIZE:
        raise ScanFormatError(
            f"{source}: encoder count {int(c[-1])} is not below {OXFORD_ENCODER_SIZE} (one turn); "
            "the file is corrupt"
        )


def check_stamps_possible(stamps_us: np.ndarray, valid: np.ndarray, source: str) -> None:
    """Raise `ScanFormatError` where the valid rows' azimuth times cannot be a sweep's: at or before
    1970 (a header of zeros, or of 0xFF bytes: −1), or one time for every row (a sweep turns for
    ~0.25 s). Read on, such a sweep would be stepped at time 0 or −1 µs; refused here it is skipped
    as unreadable by a run, as a sweep whose header breaks the time order is (``bad_timestamp``).
    The message gives the file name's time where it has one, the time the header should hold.
    """
    ts = stamps_us[valid]
    if ts.size == 0:
        return
    if ts.min() > 0 and (ts.size < 2 or ts.max() > ts.min()):
        return
    name = name_timestamp(Path(source))
    hint = "" if name is None else f" (its file name says {name})"
    if ts.min() <= 0:
        what = (f"{int((ts <= 0).sum())} of {ts.size} valid rows hold azimuth times at or before 1970 (the lowest: "
                f"{int(ts.min())} µs)")
    else:
        what = f"all {ts.size} valid rows hold the same azimuth time {int(ts[0])} µs (a sweep takes ~0.25 s)"
    raise ScanFormatError(f"{source}: {what}{hint}; the header's timestamps are corrupt — re-copy the sweep")


def azimuths_from_counts(counts: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """float64[A] azimuths (rad) = count / 5600 · 2π, with invalid rows interpolated.

    An invalid row's encoder count may be garbage, so its azimuth is interpolated linearly in
    the row index between valid neighbours (extrapolated with the mean valid step at the ends)
    to keep ``azimuths_rad`` increasing. Extrapolated end rows may fall just outside [0, 2π);
    their power is zero and they are never used.
    """
    az = counts.astype(np.float64) * (2.0 * np.pi / OXFORD_ENCODER_SIZE)
    if valid.all():
        return az
    rows = np.arange(az.size, dtype=np.float64)
    vi = np.flatnonzero(valid)
    step = (az[vi[-1]] - az[vi[0]]) / (vi[-1] - vi[0]) if vi.size > 1 else 2.0 * np.pi / az.size
    out = np.interp(rows, vi, az[vi])
    out[: vi[0]] = az[vi[0]] - step * (vi[0] - rows[: vi[0]])
    out[vi[-1] + 1 :] = az[vi[-1]] + step * (rows[vi[-1] + 1 :] - vi[-1])
    return out


def scan_from_header_image(
    img: np.ndarray,
    source: str,
    *,
    use_valid_column: bool,
    range_resolution_m: float,
    range_offset_m: float,
) -> RadarScan:
    """`RadarScan` from an Oxford-layout image whose size was already checked.

    ``use_valid_column=False`` (Boreas) treats every row as valid. Timestamps in ns are
    converted to µs; raw encoder counts are kept so `write_scan` reproduces them.
    """
    rows = split_header(img)
    if use_valid_column:
        valid = rows.valid_byte == VALID_BYTE
        if not valid.any():
            raise ScanFormatError(
                f"{source}: every azimuth row is marked invalid (column 10 is not 255 in all "
                f"{valid.size} rows); the sweep holds no data"
            )
    else:
        valid = np.ones(rows.counts.size, dtype=bool)
    check_counts_increasing(rows.counts, valid, source)
    stamps_us = to_microseconds(rows.timestamps, reference=valid)
    check_stamps_possible(stamps_us, valid, source)
    return RadarScan.from_arrays(
        stamps_us,
        azimuths_from_counts(rows.counts, valid),
        rows.power_u8,
        valid=valid,
        range_resolution_m=range_resolution_m,
        range_offset_m=range_offset_m,
        encoder_counts=rows.counts,
        source=source,
    )
