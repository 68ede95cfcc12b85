"""Trajectory files users feed to ``evo`` and KITTI tools: TUM and KITTI, from SE(2) poses.

Poses are absolute float[N, 3, 3] SE(2) matrices (`radar_odom.se2`) in the **Oxford frame**:
x forward, y right, z down, yaw positive turning x towards y. They are written as they are,
lifted to 3-D with z = 0 and the rotation about z: ``evo`` and KITTI tools read them in that
same z-down frame, so a plot viewed with z up looks mirrored (negate y and yaw to display it
z-up). Ground truth and estimates written by this module share the frame, so metrics are
unaffected.

- TUM: ``timestamp_s x y z qx qy qz qw`` per line (``qx = qy = 0``, ``qz = sin(yaw/2)``,
  ``qw = cos(yaw/2)``); timestamps written exactly from integer µs.
- KITTI: 12 numbers per line, the row-major 3×4 ``[R|t]`` with ``R = Rz(yaw)``, ``t = (x, y, 0)``.

Numbers are written with ``repr`` (shortest exact form), so reading back is lossless.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..se2 import se2_batch


def _check_poses(poses_abs, what: str) -> np.ndarray:
    p = np.asarray(poses_abs, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (3, 3):
        raise ValueError(f"{what}: poses must be float[N, 3, 3] SE(2) matrices, got shape {p.shape}")
    return p


def _yaw(r2x2: np.ndarray) -> np.ndarray:
    return np.arctan2(r2x2[..., 1, 0], r2x2[..., 0, 0])


def _open_for_writing(path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def _seconds_text(t_us: int) -> str:
    """Exact decimal seconds of an integer µs time (floats would round at 1e9 s)."""
    sign = "-" if t_us < 0 else ""
    q, r = divmod(abs(int(t_us)), 1_000_000)
    return f"{sign}{q}.{r:06d}"


def write_tum(path, timestamps_us, poses_abs) -> Path:
    """Write a TUM trajectory; ``timestamps_us`` int[N] UNIX µs, ``poses_abs`` float[N, 3, 3]."""
    p = _check_poses(poses_abs, str(path))
    ts = np.asarray(timestamps_us).reshape(-1)
    if ts.size != len(p):
        raise ValueError(f"{path}: {ts.size} timestamps for {len(p)} poses; give one per pose")
    half = 0.5 * _yaw(p[:, :2, :2])
    qz, qw = np.sin(half), np.cos(half)
    lines = [
        " ".join([_seconds_text(t)] + [repr(float(v)) for v in (x, y, 0.0, 0.0, 0.0, z, w)])
        for t, x, y, z, w in zip(ts.tolist(), p[:, 0, 2], p[:, 1, 2], qz, qw)
    ]
    out = _open_for_writing(path)
    out.write_text("".join(line + "\n" for line in lines))
    return out


def write_kitti(path, poses_abs) -> Path:
    """Write a KITTI trajectory (12 numbers per line) from float[N, 3, 3] SE(2) poses."""
    p = _check_poses(poses_abs, str(path))
    m = np.zeros((len(p), 3, 4))
    m[:, :2, :2] = p[:, :2, :2]
    m[:, 2, 2] = 1.0
    m[:, :2, 3] = p[:, :2, 2]
    out = _open_for_writing(path)
    out.write_text("".join(" ".join(repr(float(v)) for v in row) + "\n" for row in m.reshape(-1, 12)))
    return out


def _rows(path, width: int) -> list[list[str]]:
    rows = []
    for lineno, line in enumerate(Path(path).read_text().splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        if len(parts) != width:
            raise ValueError(f"{path}, line {lineno}: {len(parts)} numbers, expected {width}")
        rows.append(parts)
    return rows


def read_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """``(timestamps_us int64[N], poses float64[N, 3, 3])`` from a TUM file.

    Only x, y and the yaw of each rotation are kept (the SE(2) part).
    """
    rows = _rows(path, 8)
    ts = np.array([int(round(float(r[0]) * 1e6)) for r in rows], dtype=np.int64)
    v = np.array([[float(x) for x in r[1:]] for r in rows], dtype=np.float64).reshape(-1, 7)
    qx, qy, qz, qw = v[:, 3], v[:, 4], v[:, 5], v[:, 6]
    # yaw of the rotation's x axis projected on the x–y plane (exact for pure z rotations)
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy**2 + qz**2))
    return ts, se2_batch(np.stack([v[:, 0], v[:, 1], yaw], axis=-1))


def read_kitti(path) -> np.ndarray:
    """float64[N, 3, 3] SE(2) poses from a KITTI file (x, y and the yaw of each rotation)."""
    m = np.array([[float(x) for x in r] for r in _rows(path, 12)], dtype=np.float64).reshape(-1, 3, 4)
    return se2_batch(np.stack([m[:, 0, 3], m[:, 1, 3], _yaw(m[:, :2, :2])], axis=-1))

