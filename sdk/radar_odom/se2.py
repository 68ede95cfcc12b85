"""SE(2) poses as 3×3 homogeneous matrices, and the Oxford relative-pose convention.

Oxford convention (used everywhere in radar-odom): frames have x forward, y right (z down), and
a relative pose ``(x, y, yaw)`` is the pose of the *later* sweep's frame expressed in the
*earlier* one, so that ``T_0,k+1 = T_0,k @ se2(x, y, yaw)`` with
``se2 = [[cos, -sin, x], [sin, cos, y], [0, 0, 1]]``. A point ``p`` in the later frame is
``T @ p`` in the earlier frame. Positive yaw turns x towards y (clockwise seen from above,
since z is down).
"""
from __future__ import annotations

import numpy as np


def se2(x: float, y: float, yaw_rad: float) -> np.ndarray:
    """float64[3, 3] homogeneous transform for a pose (x, y in metres, yaw in radians)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]], dtype=np.float64)


def se2_batch(xyyaw: np.ndarray) -> np.ndarray:
    """float64[N, 3, 3] from float[N, 3] rows of (x, y, yaw)."""
    p = np.asarray(xyyaw, dtype=np.float64).reshape(-1, 3)
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    t = np.zeros((len(p), 3, 3))
    t[:, 0, 0], t[:, 0, 1], t[:, 0, 2] = c, -s, p[:, 0]
    t[:, 1, 0], t[:, 1, 1], t[:, 1, 2] = s, c, p[:, 1]
    t[:, 2, 2] = 1.0
    return t


def to_xyyaw(t: np.ndarray) -> np.ndarray:
    """(x, y, yaw) of a [3, 3] transform (or [N, 3] for [N, 3, 3]); yaw wrapped to (-π, π]."""
    t = np.asarray(t, dtype=np.float64)
    out = np.stack([t[..., 0, 2], t[..., 1, 2], np.arctan2(t[..., 1, 0], t[..., 0, 0])], axis=-1)
    return out


def invert(t: np.ndarray) -> np.ndarray:
    """Inverse of [.., 3, 3] rigid transforms, exactly (transpose of the rotation)."""
    t = np.asarray(t, dtype=np.float64)
    r = t[..., :2, :2]
    rt = np.swapaxes(r, -1, -2)
    out = np.zeros_like(t)
    out[..., :2, :2] = rt
    out[..., :2, 2] = -np.einsum("...ij,...j->...i", rt, t[..., :2, 2])
    out[..., 2, 2] = 1.0
    return out


def compose(*ts: np.ndarray) -> np.ndarray:
    """Left-to-right product ``ts[0] @ ts[1] @ ...``."""
    out = np.asarray(ts[0], dtype=np.float64)
    for t in ts[1:]:
        out = out @ np.asarray(t, dtype=np.float64)
    return out


def turn_frame(pose_xyyaw, covariance, angle_rad: float):
    """(pose, covariance) of relative poses re-expressed in frames turned by ``-angle_rad``: the
    translation turned by ``angle_rad``, the yaw kept, the covariance rotated with it.

    ``pose_xyyaw``: float[3] or [N, 3]; ``covariance``: float[3, 3] or [N, 3, 3], or None (then None
    is returned for it). A radar mounted at yaw ``m`` on its vehicle (same origin) measures
    ``T_radar``; the vehicle's relative pose is ``M T_radar M⁻¹`` with ``M = se2(0, 0, m)``:
    ``turn_frame(pose, cov, m)``.
    """
    pose = np.asarray(pose_xyyaw, dtype=np.float64)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    j = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = pose @ j.T
    out[..., 2] = pose[..., 2]
    cov = None if covariance is None else j @ np.asarray(covariance, dtype=np.float64) @ j.T
    return out, cov


def wrap_angle(a):
    """Angle(s) wrapped to (-π, π]."""
    return -((-np.asarray(a, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi)


def chain_relative(rel_xyyaw: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """Absolute poses float64[N+1, 3, 3] from N relative Oxford poses (x, y, yaw).

    ``out[0]`` is ``start`` (identity by default) and ``out[k+1] = out[k] @ se2(rel[k])``.
    """
    rel = se2_batch(rel_xyyaw)
    out = np.empty((len(rel) + 1, 3, 3))
    out[0] = np.eye(3) if start is None else start
    for k, t in enumerate(rel):
        out[k + 1] = out[k] @ t
    return out


def relative_from_absolute(abs_poses: np.ndarray) -> np.ndarray:
    """float64[N-1, 3] Oxford relative poses between consecutive absolute [N, 3, 3] poses."""
    a = np.asarray(abs_poses, dtype=np.float64)
    return to_xyyaw(invert(a[:-1]) @ a[1:])


def se2_log(pose_xyyaw) -> np.ndarray:
    """float64[3] twist (u m, v m, θ rad) whose constant-rate motion for unit time ends at ``pose``.

    The inverse of `se2_exp`: the constant body velocity (forward u, sideways v, turn θ, all per
    unit time) that carries the frame along a circular arc to the pose ``(x, y, yaw)`` (Oxford
    convention). ``θ = yaw`` (wrapped to (−π, π]); ``(u, v) = V(θ)⁻¹ (x, y)`` with
    ``V(θ) = [[sin θ/θ, −(1 − cos θ)/θ], [(1 − cos θ)/θ, sin θ/θ]]`` (the identity at θ = 0).
    """
    x, y, yaw = (float(v) for v in np.asarray(pose_xyyaw, dtype=np.float64).reshape(3))
    th = float(wrap_angle(yaw))
    half = 0.5 * th
    # (θ/2)·cot(θ/2), stable near 0 (series to θ⁴: error < 1e-12 for |θ| < 1e-3)
    a = 1.0 - th * th / 12.0 if abs(th) < 1e-3 else half / np.tan(half)
    return np.array([a * x + half * y, -half * x + a * y, th])


def se2_exp(twist) -> np.ndarray:
    """float64[3] pose (x m, y m, yaw rad) reached by the constant twist ``(u, v, θ)`` over unit time:
    a circular arc (a straight line when θ = 0); ``yaw = θ`` wrapped, ``(x, y) = V(θ) (u, v)`` (see
    `se2_log`). ``se2_exp(k · se2_log(p))`` is ``p`` repeated k times, for any real k."""
    u, v, th = (float(t) for t in np.asarray(twist, dtype=np.float64).reshape(3))
    if abs(th) < 1e-4:  # series: error < 1e-13 relative
        s, c = 1.0 - th * th / 6.0, 0.5 * th - th**3 / 24.0
    else:
        s, c = np.sin(th) / th, (1.0 - np.cos(th)) / th
    return np.array([s * u - c * v, c * u + s * v, float(wrap_angle(th))])
