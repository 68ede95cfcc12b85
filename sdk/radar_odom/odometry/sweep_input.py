"""A sweep as the graph takes it: the Cartesian image on the model's grid (or the reduced polar
sweep of a polar-input model), optionally de-skewed and drawn in a moved frame.

`graph_input` is a pure function of the sweep, the model's `ModelInfo` and, for a Cartesian
model, an optional `SweepMotion`: the sensor's velocity over the sweep (de-skew to the first
azimuth's instant) and a frame to draw the image in (the odometer's gap crossing). Only
Cartesian models can take either: a polar model's graph reads the sweep as it was recorded. A sweep-form
model (docs/sweep-form.md) draws the image inside its graph: its input is the sweep's arrays (`sweep_feeds`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..polar import filled_power, polar_to_cartesian, sampling_azimuths
from ..scan import RadarScan
from ..sweep_arrays import check_sweep_feeds

# Below this displacement over one sweep (m, and the yaw's arc at the grid's edge) de-skew moves no
# pixel by a measurable amount: the cached static maps are used instead (same image within 5 % of
# a pixel, a fraction of the cost).
_DESKEW_MIN_FRACTION_PX = 0.05
# The two sweeps of a match are drawn with one twist: a velocity that is somewhat wrong then errs
# both drawings alike, which mostly cancels in the match, where two different twists shift the
# images against each other by about half their difference over a sweep. So the new sweep takes
# the twist the reference was drawn with, and the reference is redrawn with the stream's newer
# velocity (one graph call) only once the two would draw some pixel this far apart: it bounds how
# stale the shared twist may be, not a mismatch (docs/deskew.md: the redraws and their cost).
REDRAW_FRACTION_PX = 1.0


@dataclass(frozen=True)
class SweepMotion:
    """How to draw a sweep: ``twist`` (vx m/s, vy m/s, yaw rate rad/s; body frame, constant over
    the sweep) de-skews it to its first azimuth's instant, or None; ``frame_pose`` (x m, y m,
    yaw rad; Oxford convention) is the image's frame in the sensor's frame at that instant, or
    None for the sensor frame."""

    twist: tuple | None = None
    frame_pose: tuple | None = None

    @property
    def is_identity(self) -> bool:
        return self.twist is None and self.frame_pose is None


def sweep_duration_s(scan: RadarScan) -> float:
    """Seconds from the sweep's first to its last azimuth time (0 for a sweep with one time)."""
    t = np.asarray(scan.timestamps_us, dtype=np.int64)
    return max(float(t[-1] - t[0]) * 1e-6, 0.0)


def sweep_shift_m(twist, scan: RadarScan, profile) -> float:
    """Largest displacement (m) the body ``twist`` (vx m/s, vy m/s, yaw rate rad/s; None: still)
    gives a point of the model's grid over ``scan``'s duration: the translation plus the yaw's arc
    at the grid's edge (``profile.extent_m``)."""
    if twist is None:
        return 0.0
    v = np.asarray(twist, dtype=np.float64).reshape(3)
    return sweep_duration_s(scan) * (float(np.hypot(v[0], v[1])) + abs(float(v[2])) * profile.extent_m)


def deskew_twist(velocity, scan: RadarScan, profile) -> tuple | None:
    """The twist to de-skew ``scan`` with, or None where it would move no pixel measurably.

    ``velocity``: float[3] (vx m/s, vy m/s, yaw rate rad/s; the radar's frame) or None (no
    estimate yet).
    """
    if velocity is None or profile.input_kind == "polar":
        return None
    v = np.asarray(velocity, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(v)):
        return None
    if sweep_shift_m(v, scan, profile) < _DESKEW_MIN_FRACTION_PX * profile.resolution_m:
        return None
    return tuple(float(x) for x in v)


def twists_differ(a, b, scan: RadarScan, profile) -> bool:
    """True where drawing ``scan`` with twist ``a`` instead of ``b`` (either None: still) moves some
    pixel of the model's grid by `REDRAW_FRACTION_PX` or more: the reference must then be redrawn."""
    za = np.zeros(3) if a is None else np.asarray(a, dtype=np.float64).reshape(3)
    zb = np.zeros(3) if b is None else np.asarray(b, dtype=np.float64).reshape(3)
    return sweep_shift_m(za - zb, scan, profile) >= REDRAW_FRACTION_PX * profile.resolution_m


def sweep_feeds(scan: RadarScan, info=None) -> dict[str, np.ndarray]:
    """The sweep-form graph's inputs for ``scan`` but the state: ``power`` float32[A, B] in [0, 1] (short runs
    of dropped rows filled, `radar_odom.polar.filled_power`), ``azimuths_rad`` float32[A] (those of dropped rows
    made increasing, `radar_odom.polar.sampling_azimuths`), ``range_resolution_m`` and ``range_offset_m``
    float32[1]: what `polar_to_cartesian` draws from, so the graph draws the same image.

    Checked as the SDK path checks a sweep (`radar_odom.sweep_arrays.check_sweep_feeds`; with ``info``, the
    model's `ModelInfo`, against that model too), so that a `RadarScan` made without `RadarScan.from_arrays`'s
    checks, fed to bare onnxruntime, is refused (`ScanFormatError`, `ModelMismatchError`), not matched."""
    feeds = _sweep_arrays(scan)
    check_sweep_feeds(feeds, info)
    return feeds


def _sweep_arrays(scan: RadarScan) -> dict[str, np.ndarray]:
    """`sweep_feeds` unchecked (the odometer checks the sweep, `OnnxModel.run` the feeds)."""
    return {
        "power": np.ascontiguousarray(filled_power(scan), dtype=np.float32),
        "azimuths_rad": np.ascontiguousarray(sampling_azimuths(scan), dtype=np.float32),
        "range_resolution_m": np.array([scan.range_resolution_m], dtype=np.float32),
        "range_offset_m": np.array([scan.range_offset_m], dtype=np.float32),
    }


def graph_input(scan: RadarScan, info, motion: SweepMotion | None = None):
    """float32[1, W, W] Cartesian image (or [1, A, B'] reduced polar sweep) of ``scan`` for
    the graph of the model described by ``info`` (a `ModelInfo`); ``motion`` (Cartesian models
    only) de-skews it and/or draws it in a moved frame (`SweepMotion`). A sweep-form model's input is
    the dict of `sweep_feeds` (its graph draws the image, as recorded: no ``motion``)."""
    p = info.profile
    if info.form == "sweep":
        if motion is not None and not motion.is_identity:
            raise ValueError("a sweep-form model draws the sweep as recorded: it cannot be de-skewed or moved")
        return _sweep_arrays(scan)  # checked by the odometer (check_sweep_geometry) and the model's run
    if p.input_kind == "polar":
        if motion is not None and not motion.is_identity:
            raise ValueError("a polar-input model reads the sweep as recorded: it cannot be de-skewed or moved")
        spec = info.polar_input or {}
        nb, f = int(spec.get("num_bins", scan.num_bins)), int(spec.get("bin_factor", 1))
        power = filled_power(scan)[:, : nb * f]  # short runs of dropped rows filled, as Cartesian
        if f > 1:  # mean over groups of f range bins, as the exporter's model was fed
            power = power.reshape(power.shape[0], nb, f).mean(axis=2)
        # the graph assumes row a at azimuth 2π·a/A: start from the row nearest 0 rad
        az = scan.azimuths_rad.astype(np.float64)
        first = int(np.argmin(np.minimum(az, 2 * np.pi - az)))
        if first:
            power = np.roll(power, -first, axis=0)
        return np.ascontiguousarray(power, dtype=np.float32)[None]
    if motion is None or motion.is_identity:
        # maps are cached by polar_to_cartesian per geometry, so a stream builds them once
        cart = polar_to_cartesian(scan, p.resolution_m, p.width_px, near_range_m=p.near_range_m)
    else:
        cart = polar_to_cartesian(scan, p.resolution_m, p.width_px, near_range_m=p.near_range_m,
                                  twist=motion.twist, frame_pose=motion.frame_pose)
    return cart[None]
