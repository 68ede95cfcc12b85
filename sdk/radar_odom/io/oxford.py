"""Oxford Radar RobotCar: sweep PNGs (read and write), ``radar.timestamps`` and ground truth.

Layout on disk::

    SEQ/radar/<first-azimuth µs>.png        one sweep, see `._layout`
    SEQ/radar.timestamps                    "<µs> <valid 0/1>" per sweep
    SEQ/gt/radar_odometry.csv               relative poses between consecutive sweeps

Ground-truth rows hold the pose of the later sweep (*source*) in the earlier one
(*destination*), Oxford frames (x forward, y right, z down): ``T_0,k+1 = T_0,k · se2(x, y, yaw)``.
``*_radar_timestamp`` are the PNG names, ``source/destination_timestamp`` the sweeps' mid times.
"""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import SequenceError
from ..scan import OXFORD_ENCODER_SIZE, OXFORD_RANGE_RESOLUTION_M, RadarScan
from ._layout import VALID_BYTE, check_dims, join_header, read_png_u8, scan_from_header_image

GT_RELPATH = os.path.join("gt", "radar_odometry.csv")
GT_COLUMNS = (
    "source_timestamp", "destination_timestamp", "x", "y", "z", "roll", "pitch", "yaw",
    "source_radar_timestamp", "destination_radar_timestamp",
)
# the columns read_sequence needs; the others (z, roll, pitch, mid times) are informative
GT_REQUIRED = ("source_radar_timestamp", "destination_radar_timestamp", "x", "y", "yaw")
# a relative pose between two sweeps further than this (m) is a corrupt row: 300 m is a 10-s gap at 30 m/s
MAX_STEP_M = 1e4


def load_oxford(
    path, *, range_resolution_m=None, range_offset_m=None, num_azimuths=None, num_bins=None
) -> RadarScan:
    """Read one Oxford sweep PNG (resolution defaults to 0.0432 m/bin, offset to 0)."""
    img = read_png_u8(path)
    check_dims(img, str(path), header=True, num_azimuths=num_azimuths, num_bins=num_bins)
    res = OXFORD_RANGE_RESOLUTION_M if range_resolution_m is None else range_resolution_m
    return scan_from_header_image(
        img,
        str(path),
        use_valid_column=True,
        range_resolution_m=res,
        range_offset_m=0.0 if range_offset_m is None else range_offset_m,
    )


def scan_to_image(scan: RadarScan) -> np.ndarray:
    """uint8[A, 11 + B] Oxford-layout pixels of a sweep.

    Encoder counts are the scan's raw ones when it has them (byte-exact round trip), else
    ``round(azimuth / 2π · 5600)``. Invalid rows get flag 0 (and zero power, as `RadarScan`
    zeroes them); valid rows get 255.
    """
    if scan.encoder_counts is not None:
        counts = np.asarray(scan.encoder_counts, dtype=np.uint16)
    else:
        turns = np.asarray(scan.azimuths_rad, dtype=np.float64) / (2.0 * np.pi)
        counts = np.clip(np.round(turns * OXFORD_ENCODER_SIZE), 0, 65535).astype(np.uint16)
    valid_byte = np.where(scan.valid, VALID_BYTE, 0).astype(np.uint8)
    # power was value/255 in float32; rounding recovers the byte exactly
    power = np.round(np.clip(scan.power, 0.0, 1.0) * np.float32(255.0)).astype(np.uint8)
    return join_header(scan.timestamps_us, counts, valid_byte, power)


def write_scan(path, scan: RadarScan) -> Path:
    """Write a sweep as an Oxford-layout PNG; returns the file written.

    ``path`` is the PNG file when it ends in ``.png``, else a folder, in which case the file is
    ``<folder>/<scan.timestamp_us>.png`` (the Oxford name). Folders are created.
    ``load_scan(write_scan(p, s))`` reproduces ``s`` exactly (see `scan_to_image`). The layout
    stores no range resolution or offset: readers take them from the format's defaults or
    their ``range_resolution_m`` / ``range_offset_m`` arguments.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        path = path / f"{scan.timestamp_us}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), scan_to_image(scan)):
        raise OSError(f"{path}: OpenCV could not write the PNG; check the folder is writable")
    return path


def write_radar_timestamps(seq_dir, timestamps_us, valid=None) -> Path:
    """Write ``SEQ/radar.timestamps``: one ``"<µs> <valid 0/1>"`` line per sweep, in order.

    ``timestamps_us`` are the PNG names (first-azimuth µs); ``valid`` defaults to all 1.
    """
    ts = np.asarray(timestamps_us, dtype=np.int64).reshape(-1)
    flags = np.ones(ts.size, dtype=np.int64) if valid is None else np.asarray(valid).astype(np.int64)
    if flags.shape != ts.shape:
        raise ValueError(f"valid has {flags.size} entries for {ts.size} timestamps")
    out = Path(seq_dir) / "radar.timestamps"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("".join(f"{t} {int(v != 0)}\n" for t, v in zip(ts.tolist(), flags.tolist())))
    return out


def oxford_gt_rows(radar_timestamps_us, mid_timestamps_us, rel_xyyaw) -> list[tuple]:
    """Ground-truth rows for consecutive sweeps, ready for `write_oxford_ground_truth`.

    Args:
        radar_timestamps_us: int[N], the sweeps' PNG names (first-azimuth µs), in time order.
        mid_timestamps_us: int[N], the sweeps' mid times (mean azimuth time, µs).
        rel_xyyaw: float[N−1, 3], row k = pose of sweep k+1 in sweep k (Oxford convention).

    Returns:
        N−1 tuples ``(source_radar_ts, dest_radar_ts, source_mid_ts, dest_mid_ts, x, y, yaw)``
        with source = the later sweep k+1, destination = the earlier sweep k.
    """
    radar = np.asarray(radar_timestamps_us, dtype=np.int64).reshape(-1).tolist()
    mid = np.asarray(mid_timestamps_us, dtype=np.int64).reshape(-1).tolist()
    rel = np.asarray(rel_xyyaw, dtype=np.float64).reshape(-1, 3)
    if len(mid) != len(radar) or len(rel) != len(radar) - 1:
        raise ValueError(
            f"need N radar and N mid timestamps and N−1 relative poses, got {len(radar)}, "
            f"{len(mid)} and {len(rel)}"
        )
    return [
        (radar[k + 1], radar[k], mid[k + 1], mid[k], *map(float, rel[k])) for k in range(len(rel))
    ]


def write_oxford_ground_truth(seq_dir, rows) -> Path:
    """Write ``SEQ/gt/radar_odometry.csv`` in the Oxford column order (z, roll, pitch = 0).

    ``rows``: iterable of ``(source_radar_ts, dest_radar_ts, source_mid_ts, dest_mid_ts, x, y,
    yaw)`` (see `oxford_gt_rows`), source = later sweep. Floats are written with ``repr`` so
    reading them back is exact.
    """
    out = Path(seq_dir) / GT_RELPATH
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [",".join(GT_COLUMNS)]
    for i, row in enumerate(rows):
        if len(row) != 7:
            raise ValueError(
                f"ground-truth row {i} has {len(row)} values, expected 7 (see oxford_gt_rows)"
            )
        src_r, dst_r, src_m, dst_m, x, y, yaw = row
        vals = [int(src_m), int(dst_m), float(x), float(y), 0.0, 0.0, 0.0, float(yaw)]
        vals += [int(src_r), int(dst_r)]
        lines.append(",".join(repr(v) for v in vals))
    out.write_text("\n".join(lines) + "\n")
    return out


def read_oxford_ground_truth(path) -> dict[tuple[int, int], np.ndarray]:
    """``{(destination_radar_ts, source_radar_ts): float64[3] (x, y, yaw)}`` from an Oxford gt CSV.

    Keyed earlier-then-later so a consecutive pair ``(ts[k], ts[k+1])`` looks its pose up
    directly. Raises `SequenceError` on a file that is not UTF-8 text, a missing column or a
    malformed row. A row holding a NaN/inf pose, or two rows for the same pair that disagree,
    leave that pair without ground truth (NaN) and issue one `GroundTruthWarning` naming the file and line numbers; rows
    repeated identically are kept once.
    """
    path = Path(path)
    nonfinite: list[int] = []
    conflicts: list[tuple[int, int]] = []
    try:
        lines = path.read_bytes().decode("utf-8-sig").splitlines()  # a BOM is harmless
    except UnicodeDecodeError as exc:
        raise SequenceError(
            f"{path}: not a text CSV (byte 0x{exc.object[exc.start]:02x} at offset {exc.start} is not UTF-8 text); "
            "the file is corrupt or not Oxford ground truth — re-copy it, or remove it to run without ground truth"
        ) from None
    except OSError as exc:
        raise SequenceError(f"{path}: cannot read the ground truth ({exc.strerror or exc})") from None
    header = (lines[0] if lines else "").strip().split(",")
    missing = [c for c in GT_REQUIRED if c not in header]
    if missing:
        raise SequenceError(
            f"{path}: ground-truth header lacks {', '.join(missing)}; expected the Oxford "
            f"columns {','.join(GT_COLUMNS)}"
        )
    col = {name: header.index(name) for name in GT_REQUIRED}
    out: dict[tuple[int, int], np.ndarray] = {}
    first_line: dict[tuple[int, int], int] = {}
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = line.strip().split(",")
        try:
            earlier = int(parts[col["destination_radar_timestamp"]])
            later = int(parts[col["source_radar_timestamp"]])
            pose = np.array([float(parts[col[c]]) for c in ("x", "y", "yaw")])
        except (IndexError, ValueError) as exc:
            raise SequenceError(
                f"{path}, line {lineno}: cannot read a ground-truth row ({exc}); expected "
                f"{len(header)} comma-separated numbers"
            ) from None
        key = (earlier, later)
        if not (np.all(np.isfinite(pose)) and np.all(np.abs(pose[:2]) <= MAX_STEP_M)
                and abs(pose[2]) <= 2 * np.pi):  # a yaw of 1e20 or an x of 1e308 is a corrupt row
            nonfinite.append(lineno)
            pose = np.full(3, np.nan)
        if key in out:
            same = np.array_equal(out[key], pose, equal_nan=True)
            if not same:
                conflicts.append((first_line[key], lineno))
                pose = np.full(3, np.nan)
        else:
            first_line[key] = lineno
        out[key] = pose
    if nonfinite or conflicts:
        import warnings

        from ..errors import GroundTruthWarning

        parts = []
        if nonfinite:
            more = f" and {len(nonfinite) - 5} more" if len(nonfinite) > 5 else ""
            parts.append(f"NaN/inf or implausible pose (beyond {MAX_STEP_M:g} m or 2π) on "
                         f"line{'s' if len(nonfinite) > 1 else ''} "
                         f"{', '.join(map(str, nonfinite[:5]))}{more}")
        if conflicts:
            more = f" and {len(conflicts) - 5} more" if len(conflicts) > 5 else ""
            parts.append("rows for the same pair that disagree on lines "
                         + ", ".join(f"{a} and {b}" for a, b in conflicts[:5]) + more)
        warnings.warn(
            f"{path}: {'; '.join(parts)}; those pairs have no ground truth (the rest is used as it is)",
            GroundTruthWarning, stacklevel=2,
        )
    return out
