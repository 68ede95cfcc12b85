"""The road and the ego drive: a smooth centreline, the ego's lane, and a speed profile.

Frames: a flat world with x, y in metres and headings in radians, the same handedness as the
Oxford vehicle frame (x forward, y right, positive yaw turns x towards y), so poses compose with
`radar_odom.se2`. The world origin is the ego pose at drive time t = 0 s (the first azimuth of
sweep 0): the ego starts at (0, 0) heading 0.

The centreline is integrated from a curvature profile that changes linearly (clothoid-like
ramps), so yaw rate never jumps. The ego path is the centreline shifted by the ego's lateral
lane offset; the speed profile along that path obeys the speed cap, the yaw-rate and
lateral-acceleration limits from curvature, and acceleration/deceleration limits (forward and
backward passes done as cumulative minima), with full stops held for a dwell time. Pose at any
time is a pure function of time (`EgoDrive.pose_at`), so every azimuth gets its exact pose.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import DriveConfig, SimConfigError

GRID_M = 0.1  # arc-length sampling of centreline and ego path


@dataclass(frozen=True)
class Road:
    """Road centreline sampled every `GRID_M` metres of arc length.

    Attributes:
        s_m: float64[N] arc length.
        xy_m: float64[N, 2] centreline points (world frame).
        heading_rad: float64[N] centreline heading (unwrapped).
        intersections_s_m: float64[M] arc length of intersection centres (side roads cross).
        turn_spans_m: float64[K, 2] (start, end) arc length of intersection turns (90°, or
            `DriveConfig.turn_angle_deg`; no buildings there).
        lane_width_m, lanes_per_direction: the carriageway (ego side is left, y < 0 locally).
    """

    s_m: np.ndarray
    xy_m: np.ndarray
    heading_rad: np.ndarray
    intersections_s_m: np.ndarray
    turn_spans_m: np.ndarray
    lane_width_m: float
    lanes_per_direction: int

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    def pose_at(self, s_m, lateral_m=0.0) -> tuple[np.ndarray, np.ndarray]:
        """Points float64[..., 2] at arc length ``s_m`` shifted ``lateral_m`` to the right
        (positive = +y side of the direction of travel), and headings float64[...]."""
        s = np.asarray(s_m, dtype=np.float64)
        head = np.interp(s, self.s_m, self.heading_rad)
        x = np.interp(s, self.s_m, self.xy_m[:, 0]) - np.sin(head) * lateral_m
        y = np.interp(s, self.s_m, self.xy_m[:, 1]) + np.cos(head) * lateral_m
        return np.stack([x, y], axis=-1), head

    def normal_at(self, s_m) -> np.ndarray:
        """Unit right-hand normals float64[..., 2] at arc length ``s_m``."""
        head = np.interp(np.asarray(s_m, dtype=np.float64), self.s_m, self.heading_rad)
        return np.stack([-np.sin(head), np.cos(head)], axis=-1)


@dataclass(frozen=True)
class EgoDrive:
    """The ego vehicle's path (sigma = its own arc length) and timing.

    Attributes:
        road: the road it drives on.
        sigma_m: float64[N] ego arc length at each centreline sample (same index as road.s_m).
        xy_m: float64[N, 2], heading_rad: float64[N] ego path points and headings.
        lateral_m: float64[N] ego offset from the centreline (negative = left lanes).
        t_s: float64[T], t_sigma_m: float64[T] time → ego arc length (non-decreasing; stops
            appear as repeated sigma), t = 0 at the start of the drive.
        start_sigma_m: ego arc length at t = 0.
        stops: float64[K, 2] (time_s, duration_s) of each full stop.
    """

    road: Road
    sigma_m: np.ndarray
    xy_m: np.ndarray
    heading_rad: np.ndarray
    lateral_m: np.ndarray
    t_s: np.ndarray
    t_sigma_m: np.ndarray
    start_sigma_m: float
    stops: np.ndarray

    def sigma_at(self, t_s) -> np.ndarray:
        """Ego arc length (m) at drive times ``t_s`` (s)."""
        return np.interp(np.asarray(t_s, dtype=np.float64), self.t_s, self.t_sigma_m)

    def pose_at_sigma(self, sigma_m) -> tuple[np.ndarray, np.ndarray]:
        """Ego-path points float64[..., 2] and headings at arc length ``sigma_m``."""
        sg = np.asarray(sigma_m, dtype=np.float64)
        x = np.interp(sg, self.sigma_m, self.xy_m[:, 0])
        y = np.interp(sg, self.sigma_m, self.xy_m[:, 1])
        return np.stack([x, y], axis=-1), np.interp(sg, self.sigma_m, self.heading_rad)

    def pose_at(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Exact ego position float64[..., 2] and yaw float64[...] at drive times ``t_s``."""
        return self.pose_at_sigma(self.sigma_at(t_s))

    def speed_at(self, t_s, dt_s: float = 1e-3) -> np.ndarray:
        """Ego speed (m/s) by central difference of arc length."""
        t = np.asarray(t_s, dtype=np.float64)
        return (self.sigma_at(t + dt_s) - self.sigma_at(t - dt_s)) / (2 * dt_s)

    def time_at_sigma(self, sigma_m) -> np.ndarray:
        """First time (s) the ego reaches arc length ``sigma_m``."""
        return np.interp(np.asarray(sigma_m, dtype=np.float64), self.t_sigma_m, self.t_s)

    def sigma_of_s(self, s_m) -> np.ndarray:
        """Ego arc length alongside centreline arc length ``s_m``."""
        return np.interp(np.asarray(s_m, dtype=np.float64), self.road.s_m, self.sigma_m)


def _u(rng: np.random.Generator, r) -> float:
    return float(rng.uniform(r[0], r[1]))


def _curvature_profile(cfg: DriveConfig, length_m: float, rng: np.random.Generator):
    """Breakpoints (s, kappa) of a piecewise-linear curvature profile, intersection centres,
    turn spans, stop requests (s_stop, dwell_s) and cruise-speed breakpoints."""
    s_pts, k_pts = [0.0], [0.0]
    inters, turns, stops = [], [], []
    cruise_s, cruise_v = [0.0], [_u(rng, cfg.cruise_speed_mps)]
    s = cfg.lead_in_m
    s_pts.append(s)
    k_pts.append(0.0)
    straight_only = cfg.constant_speed_mps is not None
    while s < length_m:
        if straight_only and cfg.constant_curvature_per_m:
            # a steady bend from the end of the lead-in: ramp into the curvature, then hold it
            s += cfg.curvature_ramp_m
            s_pts.append(s)
            k_pts.append(float(cfg.constant_curvature_per_m))
            s = max(s, length_m)
            s_pts.append(s)
            k_pts.append(float(cfg.constant_curvature_per_m))
            break
        s += _u(rng, cfg.straight_length_m) if not straight_only else length_m
        s_pts.append(s)
        k_pts.append(0.0)
        cruise_s.append(s)
        cruise_v.append(_u(rng, cfg.cruise_speed_mps))
        if straight_only:
            break
        r = rng.random()
        if r < cfg.turn_probability + cfg.bend_probability:
            is_turn = r < cfg.turn_probability
            radius = _u(rng, cfg.turn_radius_m if is_turn else cfg.bend_radius_m)
            if not is_turn:
                angle = np.deg2rad(_u(rng, cfg.bend_angle_deg))
            elif tuple(cfg.turn_angle_deg) == (90.0, 90.0):
                angle = np.pi / 2  # no draw: the same random stream as before turn_angle_deg existed
            else:
                angle = np.deg2rad(_u(rng, cfg.turn_angle_deg))
            kappa = rng.choice([-1.0, 1.0]) / radius
            ramp = min(cfg.curvature_ramp_m, angle * radius)
            arc = angle * radius - ramp  # the two half-ramps together turn kappa * ramp
            if is_turn:
                if rng.random() < cfg.stop_probability:
                    stops.append((s - 4.0, _u(rng, cfg.stop_duration_s)))
                inters.append(s + (arc + 2 * ramp) / 2)
                turns.append((s, s + arc + 2 * ramp))
            for ds, k in ((ramp, kappa), (arc, kappa), (ramp, 0.0)):
                s += ds
                s_pts.append(s)
                k_pts.append(k)
        elif r < cfg.turn_probability + cfg.bend_probability + cfg.junction_probability:
            if rng.random() < cfg.stop_probability:
                stops.append((s - 8.0, _u(rng, cfg.stop_duration_s)))
            inters.append(s)
    s_pts.append(max(s, length_m) + 1.0)
    k_pts.append(k_pts[-1] if straight_only else 0.0)
    return (np.array(s_pts), np.array(k_pts), np.array(inters), np.array(turns).reshape(-1, 2),
            stops, np.array(cruise_s), np.array(cruise_v))


def _integrate_centreline(s_pts, k_pts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample the curvature profile every GRID_M and integrate heading and position
    (trapezoid rule; the grid is fine enough that the error is far below a range bin)."""
    s = np.arange(0.0, s_pts[-1], GRID_M)
    kappa = np.interp(s, s_pts, k_pts)
    head = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * GRID_M)])
    c, sn = np.cos(head), np.sin(head)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (c[1:] + c[:-1]) * GRID_M)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (sn[1:] + sn[:-1]) * GRID_M)])
    return s, np.stack([x, y], axis=1), head


def lane_offset_m(lane: int, lanes: int, lane_width_m: float):
    """Lateral offset (m) of the centre of lane ``lane`` (0 = kerbside) on the left-hand
    carriageway (traffic keeps left); negate it for the oncoming carriageway."""
    return -(lanes - np.asarray(lane) - 0.5) * lane_width_m


def _lateral_profile(cfg: DriveConfig, s: np.ndarray, turns: np.ndarray, rng) -> np.ndarray:
    """Ego offset from the centreline (m, negative = left): lane 0 (kerbside, keep-left) with
    smoothstep lane changes to lane 1 (towards the centre) and back on straight stretches."""
    w = cfg.lane_width_m
    lat = np.full_like(s, lane_offset_m(0, cfg.lanes_per_direction, w))
    if cfg.lanes_per_direction < 2 or cfg.lane_changes_per_km <= 0 or cfg.constant_speed_mps:
        return lat
    n = rng.poisson(cfg.lane_changes_per_km * s[-1] / 1000.0)
    starts = np.sort(rng.uniform(cfg.lead_in_m + 30.0, s[-1], size=n))
    lane, last_end = 0, -np.inf
    for s0 in starts:
        length = _u(rng, cfg.lane_change_length_m)
        if s0 < last_end + 40.0:
            continue
        if turns.size and np.any((s0 < turns[:, 1] + 30.0) & (s0 + length > turns[:, 0] - 30.0)):
            continue
        target = 1 - lane
        u = np.clip((s - s0) / length, 0.0, 1.0)
        step = u * u * (3.0 - 2.0 * u)  # smoothstep: zero slope at both ends
        lat = lat + (target - lane) * w * step
        lane, last_end = target, s0 + length
    return lat


def _speed_profile(cfg: DriveConfig, sigma: np.ndarray, kappa: np.ndarray, cap_v: np.ndarray):
    """Speeds (m/s) along the ego path given |curvature| ``kappa`` (1/m): the minimum of the
    cap and the curvature limits, then the acceleration limits as cumulative minima of
    v² ± 2·a·sigma (exact for constant acceleration)."""
    k = np.maximum(kappa, 1e-9)
    v = np.minimum(cap_v, np.deg2rad(cfg.max_yaw_rate_dps) / k)
    v = np.minimum(v, np.sqrt(cfg.max_lateral_accel_mps2 / k))
    v2 = v * v
    a, d = cfg.max_accel_mps2, cfg.max_decel_mps2
    v2 = np.minimum(v2, 2 * a * sigma + np.minimum.accumulate(v2 - 2 * a * sigma))
    rev = (v2 + 2 * d * sigma)[::-1]
    v2 = np.minimum(v2, np.minimum.accumulate(rev)[::-1] - 2 * d * sigma)
    return np.sqrt(np.maximum(v2, 0.0))


def plan_drive(cfg: DriveConfig, duration_s: float, margin_m: float, rng: np.random.Generator) -> EgoDrive:
    """Plan a drive long enough for ``duration_s`` seconds plus ``margin_m`` of road beyond
    the furthest point the ego can reach (its speed never exceeds ``cfg.max_speed_mps``)."""
    vmax = cfg.constant_speed_mps if cfg.constant_speed_mps is not None else cfg.max_speed_mps
    if vmax < 0 or vmax > 100:
        raise SimConfigError(f"ego speed must be within 0..100 m/s, got {vmax}; check DriveConfig")
    length = cfg.lead_in_m + 1.05 * duration_s * vmax + margin_m
    s_pts, k_pts, inters, turns, stops, cruise_s, cruise_v = _curvature_profile(cfg, length, rng)
    s, c_xy, c_head = _integrate_centreline(s_pts, k_pts)
    lat = _lateral_profile(cfg, s, turns, rng)
    normal = np.stack([-np.sin(c_head), np.cos(c_head)], axis=1)
    p = c_xy + lat[:, None] * normal
    sigma = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    p_head = np.unwrap(np.arctan2(np.gradient(p[:, 1]), np.gradient(p[:, 0])))
    kappa = np.gradient(p_head) / np.maximum(np.gradient(sigma), 1e-9)
    # the speed limits use the largest |curvature| within ±1 m: conservative against the
    # finite-difference jitter and the linear interpolation between samples
    win = int(round(1.0 / GRID_M))
    k_abs = np.pad(np.abs(kappa), win, mode="edge")
    kappa = np.lib.stride_tricks.sliding_window_view(k_abs, 2 * win + 1).max(axis=1)

    if cfg.constant_speed_mps is not None:
        v = np.full_like(sigma, float(cfg.constant_speed_mps))
        stops = []
    else:
        cap = np.minimum(cruise_v[np.searchsorted(cruise_s, s, side="right") - 1], cfg.max_speed_mps)
        stop_idx = []
        for s_stop, dwell in stops:
            i = int(np.searchsorted(s, s_stop))
            if 0 < i < len(s) - 1:
                cap[i] = 0.0
                stop_idx.append((i, dwell))
        stops = stop_idx
        v = _speed_profile(cfg, sigma, kappa, cap)

    vsum = np.maximum(v[1:] + v[:-1], 1e-9)
    t = np.concatenate([[0.0], np.cumsum(2.0 * np.diff(sigma) / vsum)])  # exact for constant accel
    t_sig = sigma.copy()
    if cfg.constant_speed_mps is not None and cfg.constant_speed_mps <= 0:  # parked ego
        at = float(np.interp(cfg.lead_in_m, s, sigma))
        t, t_sig = np.array([-1e9, 0.0, 1e9]), np.array([at, at, at])
    stop_rows = []
    for k, (i, dwell) in enumerate(sorted(stops)):  # a held sample per stop
        j = i + k  # earlier insertions shifted the index
        t = np.insert(t, j + 1, t[j] + dwell)
        t[j + 2:] += dwell
        t_sig = np.insert(t_sig, j + 1, t_sig[j])
        stop_rows.append((t[j], dwell))
    start_sigma = float(np.interp(cfg.lead_in_m, s, sigma))
    t0 = float(np.interp(start_sigma, t_sig, t))
    t -= t0

    # move the world so that the ego starts at the origin heading along +x
    x0, y0 = np.interp(start_sigma, sigma, p[:, 0]), np.interp(start_sigma, sigma, p[:, 1])
    h0 = float(np.interp(start_sigma, sigma, p_head))
    rot = np.array([[np.cos(h0), np.sin(h0)], [-np.sin(h0), np.cos(h0)]])  # R(-h0)
    to_local = lambda xy: (xy - [x0, y0]) @ rot.T  # noqa: E731
    road = Road(
        s_m=s, xy_m=to_local(c_xy), heading_rad=c_head - h0, intersections_s_m=inters,
        turn_spans_m=turns, lane_width_m=cfg.lane_width_m,
        lanes_per_direction=cfg.lanes_per_direction,
    )
    stops_arr = np.array([(ts - t0, d) for ts, d in stop_rows]).reshape(-1, 2)
    return EgoDrive(
        road=road, sigma_m=sigma, xy_m=to_local(p), heading_rad=p_head - h0, lateral_m=lat,
        t_s=t, t_sigma_m=t_sig, start_sigma_m=start_sigma, stops=stops_arr,
    )
