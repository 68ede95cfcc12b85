"""Polar sweep → Cartesian image, in the Oxford Radar RobotCar reference geometry.

Cartesian image: float32 [W, W] at ``resolution_m`` metres per pixel; row 0 is furthest ahead
(+x forward), the column index grows towards +y (right). Pixel centre (r, c) lies at
``x = (cW - r) * resolution_m``, ``y = (c - cW) * resolution_m`` with ``cW = (W - 1) / 2``.

Polar image: float32 [A, B]; row a is the azimuth ``azimuths_rad[a]`` (0 = +x, growing towards
+y); bin b's centre is at range ``range_offset_m + (b + 0.5) * range_resolution_m`` (the
reference kit samples bin ``u = (ρ - res/2) / res``).

To interpolate across the 0/2π seam the polar image is *seam-padded*: its last row is
prepended and its first row appended, so real rows sit at padded rows 1..A. Sampling is
bilinear with ``cv2.remap`` (zero outside the image, so pixels beyond the last bin are 0).

The sampling maps depend only on the sweep geometry and the grid, so they are built once and
kept in a small LRU cache keyed by that geometry (`map_cache_info`, `clear_map_cache`).

Motion compensation (de-skew) and a moved image frame: a spinning radar takes a whole period to
sweep, so with the vehicle moving each azimuth is seen from another place. Given the sensor's
velocity (a body twist, constant over the sweep) and each azimuth's time relative to the instant
the image is to show, `moving_sample_maps` finds for each Cartesian pixel the azimuth that saw
that point and where, so the image is the scene as seen from the sensor at that one instant.
The same maps can also place the image in a frame moved from the sensor's (``frame_pose``): the
odometer uses it to centre a match on the motion predicted over a long gap. These maps depend on
the motion; building them takes ~10x the static maps' time (`moving_sample_maps`), so the last few
are kept too (`moving_map_cache_info`): the odometer draws both sweeps of a match with one twist and
keeps it until the velocity moves a pixel, so consecutive sweeps of one geometry reuse them. A
sweep's row times are compared, not hashed: they may jitter from sweep to sweep (Oxford), and maps
are reused only while that jitter moves no point by more than `MOVING_MAP_REUSE_FRACTION_PX`.
"""
from __future__ import annotations

import hashlib
import math
import threading
from collections import OrderedDict

import cv2
import numpy as np

from .errors import ConfigError, GridError, ScanFormatError

TWO_PI = 2.0 * math.pi
_CACHE_SIZE = 8
_MOVING_CACHE_SIZE = 4
# Cached moving maps serve a sweep whose row times differ from theirs by at most the time in which the
# twist moves a point of the grid this fraction of a pixel: far below what the bilinear draw resolves.
MOVING_MAP_REUSE_FRACTION_PX = 0.01


# --------------------------------------------------------------------------- pure geometry
def half_extent_m(resolution_m: float, width_px: int) -> float:
    """Distance (m) from the image centre to the centre of an edge pixel, as in the reference kit.

    ``(W/2 - 0.5) * r`` for even W and ``(W // 2) * r`` for odd W: both equal ``(W - 1)/2 * r``.
    """
    return (width_px - 1) / 2.0 * resolution_m


def seam_extended_azimuths(azimuths_rad: np.ndarray) -> np.ndarray:
    """float64[A + 2]: ``az[-1] - 2π``, the azimuths, ``az[0] + 2π`` (the seam-padded rows' angles)."""
    az = np.asarray(azimuths_rad, dtype=np.float64)
    return np.concatenate(([az[-1] - TWO_PI], az, [az[0] + TWO_PI]))


def pixel_range_bearing(resolution_m: float, width_px: int) -> tuple[np.ndarray, np.ndarray]:
    """(range m, bearing rad in [0, 2π)) of each Cartesian pixel centre, float64 [W, W] each.

    Row 0 is furthest ahead (+x), the column grows towards +y; bearing 0 is +x, growing towards +y
    (the azimuth encoder's convention). Float64: the maps built from it are computed once.
    """
    h = half_extent_m(resolution_m, width_px)
    coords = np.linspace(-h, h, width_px)
    y_m, x_m = np.meshgrid(coords, -coords)  # row 0 = +x (ahead), column grows to +y
    rho_m = np.hypot(x_m, y_m)
    phi_rad = np.arctan2(y_m, x_m)
    phi_rad[phi_rad < 0] += TWO_PI
    return rho_m, phi_rad


def cartesian_sample_maps(
    azimuths_rad: np.ndarray,
    num_bins: int,
    range_resolution_m: float,
    range_offset_m: float,
    resolution_m: float,
    width_px: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each Cartesian pixel samples the seam-padded polar image.

    Args:
        azimuths_rad: float[A], strictly increasing, in [0, 2π): angle of each polar row.
        num_bins: B, range bins per row. Bins past the last are read as zero by ``cv2.remap``;
            positions beyond ``num_bins`` are clamped there (same output, bounded maps).
        range_resolution_m, range_offset_m: bin b's centre is at ``offset + (b + 0.5) * res``.
        resolution_m: Cartesian metres per pixel. width_px: W.

    Returns:
        ``(map_bin, map_row)``: float32 [W, W] column (range bin ``u``) and row (``v``)
        positions in the padded polar image, for ``cv2.remap(padded, map_bin, map_row, ...)``.
        ``u = (ρ - offset - res/2) / res`` clamped at 0; ``v`` is φ located on the seam-extended
        azimuth list by piecewise-linear interpolation, which for uniform full-circle azimuths
        equals the reference ``v = (φ - az[0]) / (az[1] - az[0]) + 1``.
    """
    rho_m, phi_rad = pixel_range_bearing(resolution_m, width_px)
    u = (rho_m - range_offset_m - 0.5 * range_resolution_m) / range_resolution_m
    np.clip(u, 0.0, float(num_bins), out=u)
    ext = seam_extended_azimuths(azimuths_rad)
    if np.any(np.diff(ext) <= 0):
        raise ScanFormatError(
            f"azimuths must increase strictly and span less than a full turn "
            f"(first {ext[1]:.6g} rad, last {ext[-2]:.6g} rad)"
        )
    # rows of the padded image are 0..A+1 at angles `ext`; φ ∈ [0, 2π) always lies inside ext
    v = np.interp(phi_rad.ravel(), ext, np.arange(ext.size, dtype=np.float64)).reshape(phi_rad.shape)
    return u.astype(np.float32), v.astype(np.float32)


def _sensor_pose_at(tau_s: np.ndarray, twist) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x m, y m, yaw rad) arrays: the sensor's pose after ``tau_s`` seconds of the constant body
    twist ``(vx m/s, vy m/s, yaw rate rad/s)``, in its frame at τ = 0 (exact SE(2) exponential:
    an arc, not a chord, so a turning car's azimuths are placed on its path)."""
    vx, vy, w = (float(v) for v in twist)
    theta = w * tau_s
    small = np.abs(theta) < 1e-9
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)  # sinθ/θ
    b = np.where(small, 0.5 * theta, (1.0 - np.cos(safe)) / safe)  # (1 − cosθ)/θ
    x = (a * vx - b * vy) * tau_s
    y = (b * vx + a * vy) * tau_s
    return x, y, theta


def moving_sample_maps(
    azimuths_rad: np.ndarray,
    azimuth_times_s: np.ndarray,
    twist,
    frame_pose,
    num_bins: int,
    range_resolution_m: float,
    range_offset_m: float,
    resolution_m: float,
    width_px: int,
    iterations: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """`cartesian_sample_maps` for a moving sensor and/or a moved image frame.

    Args:
        azimuths_rad: float[A] strictly increasing in [0, 2π): each polar row's angle.
        azimuth_times_s: float[A]: each row's time (s) relative to the instant the image shows
            (0 for the row seen at that instant; the sweep's first azimuth for the odometer).
        twist: ``(vx m/s, vy m/s, yaw rate rad/s)``, the sensor's body twist, constant over the
            sweep (x forward, y right, yaw from x towards y), or None for a still sensor.
        frame_pose: ``(x m, y m, yaw rad)``: the image's frame in the sensor frame at that
            instant (Oxford convention), or None for the sensor frame itself.
        num_bins, range_resolution_m, range_offset_m, resolution_m, width_px: as in
            `cartesian_sample_maps`.
        iterations: fixed-point steps finding the azimuth that saw each pixel (the azimuth
            decides the time, the time the sensor's pose, the pose the azimuth); the update
            shrinks by the turn the sensor makes between neighbouring azimuths, so three steps
            are exact to far below a bin at road speeds.

    Returns:
        ``(map_bin, map_row)`` float32 [W, W], as `cartesian_sample_maps`. With ``twist`` and
        ``frame_pose`` both None they equal `cartesian_sample_maps`'s exactly.

    A static point at position q of the image is seen by the row whose angle is the bearing of
    q from where the sensor was at that row's time: ``p = S(τ)⁻¹ · F · q`` with F the frame
    pose and S(τ) the sensor pose after τ. Rows next to the seam were seen one period apart,
    so at the seam the row time is interpolated between the last and the first row's times.
    """
    h = half_extent_m(resolution_m, width_px)
    coords = np.linspace(-h, h, width_px)
    y_q, x_q = np.meshgrid(coords, -coords)  # row 0 = +x (ahead), column grows to +y
    if frame_pose is not None:
        fx, fy, fyaw = (float(v) for v in frame_pose)
        c, s_ = math.cos(fyaw), math.sin(fyaw)
        x_q, y_q = c * x_q - s_ * y_q + fx, s_ * x_q + c * y_q + fy
    ext = seam_extended_azimuths(azimuths_rad)
    if np.any(np.diff(ext) <= 0):
        raise ScanFormatError(
            f"azimuths must increase strictly and span less than a full turn "
            f"(first {ext[1]:.6g} rad, last {ext[-2]:.6g} rad)"
        )
    x_m, y_m = x_q, y_q
    if twist is not None and any(float(v) != 0.0 for v in twist):
        tau = np.asarray(azimuth_times_s, dtype=np.float64)
        if tau.shape != (ext.size - 2,):
            raise ScanFormatError(f"azimuth_times_s must hold one time per azimuth ({ext.size - 2}), got {tau.shape}")
        tau_ext = np.concatenate(([tau[-1]], tau, [tau[0]]))
        phi = np.mod(np.arctan2(y_q, x_q), TWO_PI)
        for _ in range(max(int(iterations), 1)):
            t = np.interp(phi.ravel(), ext, tau_ext).reshape(phi.shape)
            sx, sy, syaw = _sensor_pose_at(t, twist)
            c, s_ = np.cos(syaw), np.sin(syaw)
            dx, dy = x_q - sx, y_q - sy
            x_m, y_m = c * dx + s_ * dy, -s_ * dx + c * dy  # R(−yaw)·(q − t)
            phi = np.mod(np.arctan2(y_m, x_m), TWO_PI)
    rho_m = np.hypot(x_m, y_m)
    phi_rad = np.mod(np.arctan2(y_m, x_m), TWO_PI)
    phi_rad[phi_rad >= TWO_PI] = 0.0  # mod can round up to 2π for a tiny negative angle
    u = (rho_m - range_offset_m - 0.5 * range_resolution_m) / range_resolution_m
    np.clip(u, 0.0, float(num_bins), out=u)
    v = np.interp(phi_rad.ravel(), ext, np.arange(ext.size, dtype=np.float64)).reshape(phi_rad.shape)
    return u.astype(np.float32), v.astype(np.float32)


def near_range_bins(near_range_m: float, range_resolution_m: float, range_offset_m: float, num_bins: int) -> int:
    """How many leading bins have their centre closer than ``near_range_m`` (these get blanked)."""
    if near_range_m <= 0:
        return 0
    # bin b is blanked iff offset + (b + 0.5) * res < near  <=>  b < t
    t = (near_range_m - range_offset_m) / range_resolution_m - 0.5
    return int(min(max(math.ceil(t), 0), num_bins))


# --------------------------------------------------------------------------- map cache
class _LRU:
    """A small thread-safe LRU of built sampling maps, with build and hit counts (`map_cache_info`)."""

    def __init__(self, size: int):
        self.size = size
        self._entries: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self.builds = 0
        self.hits = 0

    def _lookup(self, key, usable=lambda entry: True):
        """The entry under ``key`` where ``usable(entry)`` (counted as a hit, made the newest), else None."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None or not usable(entry):
                return None
            self._entries.move_to_end(key)
            self.hits += 1
            return entry

    def _store(self, key, entry):
        """Keep ``entry`` under ``key`` as the newest (counted as a build), the oldest beyond ``size`` evicted."""
        with self._lock:
            self._entries[key] = entry
            self._entries.move_to_end(key)
            while len(self._entries) > self.size:
                self._entries.popitem(last=False)
            self.builds += 1
        return entry

    def info(self) -> dict:
        return {"builds": self.builds, "hits": self.hits, "entries": len(self._entries), "max_entries": self.size}

    def clear(self):
        with self._lock:
            self._entries.clear()
            self.builds = 0
            self.hits = 0


class _MapCache(_LRU):
    """(map_bin, map_row, bins_used) per sweep geometry and grid."""

    def get(self, az_rad: np.ndarray, num_bins, range_res, range_off, resolution_m, width_px):
        key = _geometry_key(az_rad, num_bins, range_res, range_off, resolution_m, width_px)
        entry = self._lookup(key)
        if entry is not None:
            return entry
        map_bin, map_row = cartesian_sample_maps(az_rad, num_bins, range_res, range_off, resolution_m, width_px)
        # bilinear sampling at u reads bins floor(u) and floor(u)+1: copying only those columns of
        # the (long) polar rows gives the same output for a fraction of the copy
        bins_used = int(min(num_bins, math.floor(float(map_bin.max())) + 2))
        return self._store(key, (map_bin, map_row, bins_used))


def _geometry_key(az_rad: np.ndarray, num_bins, range_res, range_off, resolution_m, width_px) -> tuple:
    """What sampling maps depend on besides the motion: the sweep's geometry and the grid."""
    return (int(az_rad.size), int(num_bins), float(range_res), float(range_off), _azimuth_fingerprint(az_rad),
            float(resolution_m), int(width_px))


def _azimuth_fingerprint(az_rad: np.ndarray) -> bytes:
    """Cheap identity of an azimuth list: its values rounded to 1 µrad, hashed."""
    micro = np.round(np.asarray(az_rad, dtype=np.float64) * 1e6).astype(np.int64)
    return hashlib.blake2b(micro.tobytes(), digest_size=16).digest()


_CACHE = _MapCache(_CACHE_SIZE)


class _MovingMapCache(_LRU):
    """The last few `moving_sample_maps` results, keyed by geometry, grid, twist and frame; an entry serves
    a sweep whose row times are within the reuse tolerance of its own (module docstring)."""

    def get(self, az_rad, azimuth_times_s, twist, frame_pose, num_bins, range_res, range_off, resolution_m,
            width_px):
        tau = np.asarray(azimuth_times_s, dtype=np.float64)
        key = (
            *_geometry_key(az_rad, num_bins, range_res, range_off, resolution_m, width_px),
            None if twist is None else tuple(float(v) for v in twist),
            None if frame_pose is None else tuple(float(v) for v in frame_pose),
        )
        entry = self._lookup(key, lambda e: _times_interchangeable(e[0], tau, twist, resolution_m, width_px))
        if entry is None:
            maps = moving_sample_maps(az_rad, tau, twist, frame_pose, num_bins, range_res, range_off,
                                      resolution_m, width_px)
            entry = self._store(key, (tau.copy(), maps))
        return entry[1]


def _times_interchangeable(tau_a_s: np.ndarray, tau_b_s: np.ndarray, twist, resolution_m: float,
                           width_px: int) -> bool:
    """True where drawing with row times ``tau_b_s`` instead of ``tau_a_s`` (float[A], s) moves no point of the
    grid by `MOVING_MAP_REUSE_FRACTION_PX` of a pixel under ``twist`` (vx m/s, vy m/s, yaw rate rad/s; None: still):
    the largest time difference times the fastest point's speed (translation plus the yaw at the grid's corner)."""
    if tau_a_s.shape != tau_b_s.shape:
        return False
    if twist is None:
        return True
    vx, vy, w = (float(v) for v in twist)
    speed_m_s = math.hypot(vx, vy) + abs(w) * math.sqrt(2.0) * half_extent_m(resolution_m, width_px)
    worst_s = float(np.max(np.abs(tau_a_s - tau_b_s))) if tau_a_s.size else 0.0
    return worst_s * speed_m_s <= MOVING_MAP_REUSE_FRACTION_PX * float(resolution_m)


_MOVING_CACHE = _MovingMapCache(_MOVING_CACHE_SIZE)


def moving_map_cache_info() -> dict:
    """``{"builds", "hits", "entries", "max_entries"}`` of the de-skew / moved-frame map cache."""
    return _MOVING_CACHE.info()


def map_cache_info() -> dict:
    """``{"builds", "hits", "entries", "max_entries"}`` of the sampling-map cache."""
    return _CACHE.info()


def clear_map_cache() -> None:
    """Forget every cached map, static and moving (and reset the counters)."""
    _CACHE.clear()
    _MOVING_CACHE.clear()


# --------------------------------------------------------------------------- conversion
MAX_GRID_PX = 4096  # the widest grid drawn: 8x the widest profile (cart-0.2, 512 px); its two maps take 128 MiB


def check_grid(resolution_m: float, width_px) -> int:
    """``width_px`` as an int where (``resolution_m`` m/px, ``width_px`` px a side) is a grid to draw; else
    `ConfigError` (resolution not > 0, width not a whole number ≥ 2) or `GridError` (wider than `MAX_GRID_PX`:
    its float32 sample maps alone would take gigabytes and end in numpy's MemoryError)."""
    try:
        ok = float(resolution_m) > 0 and math.isfinite(float(resolution_m)) and int(width_px) == width_px
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok or int(width_px) < 2:
        raise ConfigError(f"resolution_m must be a finite number > 0 and width_px a whole number >= 2 (got "
                          f"{resolution_m!r}, {width_px!r}); e.g. 0.4 m/px and 256 px, the cart-0.4 grid")
    if int(width_px) > MAX_GRID_PX:
        gib = 2 * 4 * int(width_px) ** 2 / 2**30
        raise GridError(f"width_px={int(width_px)}: a grid that wide needs {gib:.1f} GiB of sample maps; give at most "
                        f"{MAX_GRID_PX} px (the shipped grids are 128-512 px), or a coarser resolution_m")
    return int(width_px)


def polar_to_cartesian(scan, resolution_m: float, width_px: int, near_range_m: float = 0.0, out=None, *,
                       twist=None, frame_pose=None) -> np.ndarray:
    """Cartesian image float32 [W, W] of a `RadarScan` (see the module docstring for the frames).

    Args:
        scan: a `RadarScan`; its invalid rows are already zero.
        resolution_m: metres per pixel. width_px: W.
        near_range_m: power at bins whose centre is closer than this is zeroed before sampling
            (the vehicle's own returns; Oxford practice ≈ 2.5 m). 0 keeps everything.
        out: optional float32 [W, W] C-contiguous array to write into (no allocation per sweep).
        twist: optional ``(vx m/s, vy m/s, yaw rate rad/s)`` of the sensor over the sweep: the
            sweep is de-skewed to the instant of its first azimuth (``scan.timestamp_us``), using
            each row's timestamp (`moving_sample_maps`).
        frame_pose: optional ``(x m, y m, yaw rad)``: draw the image in this frame, given in the
            sensor's frame at that instant, instead of the sensor's own.
    """
    width_px = check_grid(resolution_m, width_px)
    az = sampling_azimuths(scan)
    maps = None
    if twist is not None or frame_pose is not None:
        maps = _MOVING_CACHE.get(az, azimuth_times_s(scan), twist, frame_pose, scan.num_bins,
                                 scan.range_resolution_m, scan.range_offset_m, resolution_m, width_px)
    return _remap(
        fill_dropped_rows(scan.power, az, scan.valid), az, scan.range_resolution_m, scan.range_offset_m,
        resolution_m, width_px, near_range_m, out, source=scan.source, maps=maps,
    )


def filled_power(scan) -> np.ndarray:
    """float32[A, B]: a `RadarScan`'s power with its short runs of dropped rows filled
    (`fill_dropped_rows`), as every graph input draws it."""
    return fill_dropped_rows(scan.power, sampling_azimuths(scan), scan.valid)


# Dropped azimuth rows in runs of at most this many are filled from their neighbours. The beam
# is ~2° wide, so a row between two valid ones 2-3 rows apart (0.9° each on a Navtech) holds
# nearly what they hold; a longer run is a real hole in the sweep and stays empty.
MAX_FILLED_RUN_ROWS = 2


def fill_dropped_rows(power: np.ndarray, az_rad: np.ndarray, valid: np.ndarray,
                      max_run: int = MAX_FILLED_RUN_ROWS) -> np.ndarray:
    """``power`` float[A, B] with each run of at most ``max_run`` invalid rows (azimuth order,
    wrapping at the seam) replaced by the linear interpolation, in azimuth, of the valid rows on
    either side; longer runs stay as they are (zero). The input when every row is valid.

    Why: an invalid row is zero. Drawn as it is, a radar that drops the same rows in every sweep
    (every other row, every third) paints a stripe pattern fixed to the sensor into every image,
    and that pattern matches itself best at zero motion: the matches read as standing still.
    """
    valid = np.asarray(valid, dtype=bool)
    if valid.all() or valid.sum() < 2:
        return power
    a = valid.size
    v_idx = np.flatnonzero(valid)
    rows = np.arange(a)
    # the valid rows before and after each row, wrapping (index into v_idx)
    after = np.searchsorted(v_idx, rows, side="left") % v_idx.size
    before = (after - 1) % v_idx.size
    prev_row, next_row = v_idx[before], v_idx[after]
    run = (next_row - prev_row - 1) % a  # invalid rows between the two valid neighbours
    fill = ~valid & (run <= max_run)
    if not fill.any():
        return power
    az = np.asarray(az_rad, dtype=np.float64)
    span = (az[next_row] - az[prev_row]) % TWO_PI
    into = (az - az[prev_row]) % TWO_PI
    w = np.where(span > 0, into / np.where(span > 0, span, 1.0), 0.5)[fill, None]
    out = np.array(power, dtype=np.float32, copy=True)
    out[fill] = (1.0 - w) * out[prev_row[fill]] + w * out[next_row[fill]]
    return out


def azimuth_times_s(scan) -> np.ndarray:
    """float64[A]: each row's time in s after the sweep's first azimuth (``scan.timestamp_us``).

    Invalid rows may carry junk times (a dropped azimuth): theirs are interpolated by row index
    from the valid rows, so the times stay in row order.
    """
    t = (np.asarray(scan.timestamps_us, dtype=np.int64) - int(scan.timestamp_us)).astype(np.float64) * 1e-6
    valid = np.asarray(scan.valid, dtype=bool)
    if valid.all() or valid.sum() < 2:
        return t
    rows = np.arange(t.size, dtype=np.float64)
    v_idx = np.flatnonzero(valid)
    slope = float(np.polyfit(v_idx, t[v_idx], 1)[0])
    out = np.interp(rows, v_idx, t[v_idx])
    out[: v_idx[0]] = t[v_idx[0]] - slope * (v_idx[0] - rows[: v_idx[0]])
    out[v_idx[-1] + 1:] = t[v_idx[-1]] + slope * (rows[v_idx[-1] + 1:] - v_idx[-1])
    return out


def polar_to_cartesian_array(
    power,
    azimuths_rad,
    range_resolution_m: float,
    range_offset_m: float,
    resolution_m: float,
    width_px: int,
    near_range_m: float = 0.0,
    out=None,
) -> np.ndarray:
    """Like `polar_to_cartesian` for bare arrays: ``power`` [A, B] (float, or uint8 scaled by
    1/255) and ``azimuths_rad`` [A] strictly increasing in [0, 2π)."""
    where = "polar_to_cartesian_array: "
    width_px = check_grid(resolution_m, width_px)
    power = np.asarray(power)
    if power.ndim != 2 or power.shape[0] < 2 or power.shape[1] < 2:
        raise ScanFormatError(f"{where}power must be a 2-D array [azimuths, bins], got shape {power.shape}")
    if power.dtype == np.uint8:
        power = power.astype(np.float32) / np.float32(255.0)
    elif not (np.issubdtype(power.dtype, np.floating) or np.issubdtype(power.dtype, np.integer)):
        raise ScanFormatError(f"{where}power must be numeric, got {power.dtype}")
    az = np.asarray(azimuths_rad, dtype=np.float64)
    if az.shape != (power.shape[0],):
        raise ScanFormatError(
            f"{where}azimuths_rad has shape {az.shape} but power has {power.shape[0]} rows; give one angle per row"
        )
    _check_azimuths(az, where)
    return _remap(power, az, range_resolution_m, range_offset_m, resolution_m, width_px, near_range_m, out, "arrays")


def _remap(power, az_rad, range_res, range_off, resolution_m, width_px, near_range_m, out, source,
           maps=None) -> np.ndarray:
    width_px = check_grid(resolution_m, width_px)
    if not range_res > 0:
        raise ScanFormatError(f"{source}: range_resolution_m must be > 0 (got {range_res})")
    width_px = int(width_px)
    a, b = power.shape
    if maps is None:
        map_bin, map_row, bins_used = _CACHE.get(az_rad, b, range_res, range_off, resolution_m, width_px)
    else:
        map_bin, map_row = maps
        bins_used = int(min(b, math.floor(float(map_bin.max())) + 2))
    padded = np.empty((a + 2, bins_used), dtype=np.float32)
    padded[1:-1] = power[:, :bins_used]
    padded[0] = power[-1, :bins_used]
    padded[-1] = power[0, :bins_used]
    n_blank = near_range_bins(near_range_m, range_res, range_off, bins_used)
    if n_blank:
        padded[:, :n_blank] = 0.0
    if out is not None:
        if out.shape != (width_px, width_px) or out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ConfigError(
                f"out must be a C-contiguous float32 array of shape ({width_px}, {width_px}), "
                f"got {out.dtype} {out.shape}"
            )
    result = cv2.remap(
        padded, map_bin, map_row, cv2.INTER_LINEAR, dst=out,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0,
    )
    return result


def _check_azimuths(az: np.ndarray, where: str) -> None:
    if not np.all(np.isfinite(az)):
        raise ScanFormatError(f"{where}azimuths_rad holds NaN/inf")
    if np.any(np.diff(az) <= 0):
        row = int(np.flatnonzero(np.diff(az) <= 0)[0]) + 1
        raise ScanFormatError(f"{where}azimuths must increase strictly (row {row}); check the azimuth order")
    if az[0] < 0 or az[-1] >= TWO_PI + 1e-6:
        raise ScanFormatError(f"{where}azimuths_rad must lie in [0, 2π), got [{az[0]:.4g}, {az[-1]:.4g}]")


def sampling_azimuths(scan) -> np.ndarray:
    """float64[A] azimuths to sample with: the scan's, with those of invalid rows made consistent.

    Invalid rows hold zero power but may carry junk angles (a dropped encoder reading); the map
    needs a strictly increasing list, so their angles are interpolated from the valid rows by row
    index (extrapolated by the median step at the ends).
    """
    az = np.asarray(scan.azimuths_rad, dtype=np.float64)
    valid = np.asarray(scan.valid, dtype=bool)
    if valid.all() or (np.all(np.diff(az) > 0) and az[0] >= 0 and az[-1] < TWO_PI):
        return az
    rows = np.arange(az.size)
    v_idx = np.flatnonzero(valid)
    step = float(np.median(np.diff(az[v_idx]) / np.diff(v_idx))) if v_idx.size > 1 else TWO_PI / az.size
    filled = np.interp(rows, v_idx, az[v_idx])
    first, last = int(v_idx[0]), int(v_idx[-1])
    lead, trail = rows[:first], rows[last + 1:]
    filled[:first] = az[first] - step * (first - lead)
    filled[last + 1:] = az[last] + step * (trail - last)
    # a dropped row next to the seam may have no room at the nominal step: spread such rows evenly
    # in the gap left before 0 / after 2π (their power is zero, only their order matters)
    if first and filled[0] < 0:
        filled[:first] = az[first] * lead / first
    if trail.size and filled[-1] >= TWO_PI:
        filled[last + 1:] = az[last] + (TWO_PI - az[last]) * (trail - last) / (trail.size + 1)
    _check_azimuths(filled, f"{scan.source}: azimuths of the invalid rows cannot be inferred: ")
    return filled
