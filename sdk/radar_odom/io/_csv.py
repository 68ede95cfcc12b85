"""Reading pose CSVs whose first column is a timestamp, with `SequenceError` on bad files."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import SequenceError


def _stamp(text: str) -> int:
    """An integer timestamp (µs or ns) as written; a decimal one is taken as seconds → µs."""
    text = text.strip()
    if text.lstrip("-").isascii() and text.lstrip("-").isdigit():
        return int(text)  # parsed as int: ns stamps (~1.7e18) would lose digits in a float
    us = float(text) * 1e6
    if not math.isfinite(us):
        raise ValueError(f"timestamp {text[:30]!r} is not a finite number")
    return int(round(us))


def read_numeric_csv(path, *, required=(), num_columns=None):
    """``(names, stamps int64[M], values float64[M, K])`` from a comma-separated pose file.

    The first line is a header when its first field is not a number (``names`` is then the
    list of column names, else None). ``required`` columns must be in the header (a headerless
    file fails); ``num_columns`` (stamp included) is checked on every row. Integer stamps are
    returned as written (µs or ns); decimal ones are read as seconds and returned in µs.
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{path}: cannot read the pose file ({exc})") from None
    lines = [ln for ln in lines if ln.strip()]
    names = None
    if lines:
        first = lines[0].split(",")[0].strip()
        try:
            _stamp(first)
        except ValueError:
            names = [c.strip() for c in lines[0].split(",")]
            lines = lines[1:]
    if required:
        missing = [c for c in required if names is None or c not in names]
        if missing:
            raise SequenceError(
                f"{path}: header lacks {', '.join(missing)}; expected a header line with "
                f"{','.join(required)}"
            )
    width = num_columns or (len(names) if names else None)
    if not lines:
        raise SequenceError(f"{path}: the pose file holds no rows")
    stamps = np.empty(len(lines), dtype=np.int64)
    values = []
    start = 2 if names else 1
    for i, line in enumerate(lines):
        parts = line.split(",")
        if width is not None and len(parts) != width:
            raise SequenceError(
                f"{path}, line {i + start}: {len(parts)} columns, expected {width}; the file is "
                "truncated or not this dataset's pose file"
            )
        try:
            stamps[i] = _stamp(parts[0])
            values.append([float(p) for p in parts[1:]])
        except (ValueError, OverflowError) as exc:
            raise SequenceError(f"{path}, line {i + start}: not a number ({exc})") from None
    values = np.asarray(values, dtype=np.float64).reshape(len(lines), -1)
    return names, *_drop_bad_rows(path, stamps, values, start)


MAX_POSE_VALUE = 1e8  # m or rad: UTM northings are below 1e7, an angle or a rotation entry below 10


def _drop_bad_rows(path, stamps, values, start):
    """Rows with a NaN/inf value or one beyond `MAX_POSE_VALUE` (no coordinate, angle or rotation
    entry of a pose is that large: a yaw of 1e20 or an x of 1e308 is a corrupt row), and rows
    repeating a stamp with other values, are dropped (identical repeats are kept once), with one
    `GroundTruthWarning` naming their lines."""
    with np.errstate(invalid="ignore"):
        finite = np.all(np.isfinite(values) & (np.abs(values) <= MAX_POSE_VALUE), axis=1)
    keep = finite.copy()
    seen: dict[int, int] = {}
    conflicts = []
    for i in np.flatnonzero(finite).tolist():
        t = int(stamps[i])
        j = seen.get(t)
        if j is None:
            seen[t] = i
        elif np.array_equal(values[i], values[j]):
            keep[i] = False
        else:
            conflicts.append((j, i))
            keep[i] = keep[j] = False
    if keep.all():
        return stamps, values
    import warnings

    from ..errors import GroundTruthWarning

    parts = []
    bad = (np.flatnonzero(~finite) + start).tolist()
    if bad:
        more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
        lines = f"line{'s' if len(bad) > 1 else ''} {', '.join(map(str, bad[:5]))}{more}"
        parts.append(f"NaN/inf or implausible (beyond {MAX_POSE_VALUE:.0e}) values on {lines}")
    if conflicts:
        more = f" and {len(conflicts) - 5} more" if len(conflicts) > 5 else ""
        parts.append("different poses for the same time on lines "
                     + ", ".join(f"{a + start} and {b + start}" for a, b in conflicts[:5]) + more)
    if parts:
        warnings.warn(f"{path}: {'; '.join(parts)}; those rows are left out", GroundTruthWarning, stacklevel=3)
    if not keep.any():
        raise SequenceError(f"{path}: no usable pose row (every row is non-finite or conflicting)")
    return stamps[keep], values[keep]
