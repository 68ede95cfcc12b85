"""From absolute z-up poses (Boreas ENU, MulRan) to Oxford relative poses (z down).

Boreas and MulRan give absolute poses ``T_world_body`` (4×4) of a body frame with x forward,
y left, z up. The relative motion between consecutive sweeps is ``T_k⁻¹ · T_k+1`` (3-D, so a
slope does not shorten the step), whose planar part is ``(x, y_left, yaw_ccw)`` with
``yaw = atan2(R[1,0], R[0,0])``. Oxford frames have y right and z down: the same motion is
the mirror image through the x–z plane, i.e. ``(x, −y_left, −yaw_ccw)``. (Conjugating by
``diag(1, −1)`` maps SE(2) to SE(2), so chaining the converted relatives gives the mirrored
trajectory exactly.)
"""
from __future__ import annotations

import numpy as np


def rotation_zyx(yaw, pitch, roll) -> np.ndarray:
    """float64[M, 3, 3] ``Rz(yaw) · Ry(pitch) · Rx(roll)`` (active, angles in rad, z up)."""
    y, p, r = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (yaw, pitch, roll))
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    out = np.empty((y.size, 3, 3))
    out[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1)
    out[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1)
    out[:, 2] = np.stack([-sp, cp * sr, cp * cr], -1)
    return out


def oxford_relative_from_zup(t_world_body: np.ndarray) -> np.ndarray:
    """float64[N−1, 3] Oxford ``(x, y, yaw)`` of sweep k+1 in sweep k from z-up float[N, 4, 4].

    NaN poses (no ground truth for a sweep) give NaN rows.
    """
    t = np.asarray(t_world_body, dtype=np.float64)
    r0, p0 = t[:-1, :3, :3], t[:-1, :3, 3]
    r1, p1 = t[1:, :3, :3], t[1:, :3, 3]
    r0t = np.swapaxes(r0, -1, -2)
    rel_r = r0t @ r1
    rel_p = np.einsum("nij,nj->ni", r0t, p1 - p0)
    yaw_ccw = np.arctan2(rel_r[:, 1, 0], rel_r[:, 0, 0])
    return np.stack([rel_p[:, 0], -rel_p[:, 1], -yaw_ccw], axis=-1)


def nearest_poses(query_us, stamps_us, poses, max_gap_us: int) -> np.ndarray:
    """Pose with the nearest stamp for each query time, NaN where none is within ``max_gap_us``.

    Args:
        query_us: int[N] times to look up; stamps_us: int[M] pose times (any order);
        poses: float[M, ...] poses; max_gap_us: largest accepted |query − stamp|.
    """
    q = np.asarray(query_us, dtype=np.int64)
    order = np.argsort(stamps_us, kind="stable")
    s = np.asarray(stamps_us, dtype=np.int64)[order]
    hi = np.clip(np.searchsorted(s, q), 1, len(s) - 1) if len(s) > 1 else np.zeros(len(q), dtype=int)
    lo = np.maximum(hi - 1, 0)
    pick = np.where(np.abs(s[lo] - q) <= np.abs(s[hi] - q), lo, hi)
    out = np.asarray(poses, dtype=np.float64)[order][pick].copy()
    out[np.abs(s[pick] - q) > max_gap_us] = np.nan
    return out
