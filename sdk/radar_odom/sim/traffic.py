"""Moving traffic: vehicles and cyclists (boxes) and pedestrians (point scatterers).

Three kinds of track, each a pure function of time so every azimuth sees the object where it
is at that azimuth's instant:

* road tracks: arc length ``s0 + v·t`` along the centreline at a fixed lateral offset
  (oncoming vehicles, same-direction traffic in other lanes, cyclists, pedestrians);
* ego tracks: the ego's own arc length plus a fixed gap along the ego path (vehicles
  *following the ego at its speed*: static in the sensor frame, the worst distractor);
* line tracks: ``p0 + velocity·(t - t_cross)`` straight across an intersection (crossing traffic).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import DriveConfig, TrafficConfig
from .drive import EgoDrive, lane_offset_m

LINE_TRACK_HALF_LENGTH_M = 200.0


@dataclass(frozen=True)
class Traffic:
    """Arrays describing every moving object of a drive (one row per object).

    Boxes: ``kind`` (0 road, 1 ego-follower, 2 line), per-kind parameters ``s0_m``
    (road: arc length at t=0; ego: gap along the ego path), ``speed_mps`` (signed along the
    road for road tracks), ``lateral_m``, ``p0_m``/``vel_mps``/``t_cross_s`` (line tracks),
    ``length_m``, ``width_m``, ``refl_db``, ``trans_db``. Pedestrians: road tracks
    ``ped_s0_m``, ``ped_speed_mps``, ``ped_lateral_m``, ``ped_refl_db``.
    """

    kind: np.ndarray
    s0_m: np.ndarray
    speed_mps: np.ndarray
    lateral_m: np.ndarray
    p0_m: np.ndarray
    vel_mps: np.ndarray
    t_cross_s: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    refl_db: np.ndarray
    trans_db: np.ndarray
    ped_s0_m: np.ndarray
    ped_speed_mps: np.ndarray
    ped_lateral_m: np.ndarray
    ped_refl_db: np.ndarray

    @property
    def num_boxes(self) -> int:
        return len(self.kind)

    def box_poses(self, drive: EgoDrive, t_s: np.ndarray, idx: np.ndarray | None = None):
        """Centres float64[T, N, 2], headings float64[T, N] and an active mask bool[T, N] of the
        boxes ``idx`` (all by default) at times ``t_s`` float64[T]."""
        idx = np.arange(self.num_boxes) if idx is None else np.asarray(idx)
        t = np.asarray(t_s, dtype=np.float64).reshape(-1, 1)
        road = drive.road
        n = len(idx)
        centre = np.zeros((len(t), n, 2))
        head = np.zeros((len(t), n))
        active = np.ones((len(t), n), dtype=bool)
        k = self.kind[idx]
        for kind in (0, 1, 2):
            sel = np.flatnonzero(k == kind)
            if not len(sel):
                continue
            j = idx[sel]
            if kind == 0:
                s = self.s0_m[j] + self.speed_mps[j] * t
                c, h = road.pose_at(s, self.lateral_m[j])
                h = h + np.where(self.speed_mps[j] < 0, np.pi, 0.0)
                act = (s > 0) & (s < road.length_m)
            elif kind == 1:
                sg = drive.sigma_at(t) + self.s0_m[j]
                c, h = drive.pose_at_sigma(sg)
                act = np.ones_like(sg, dtype=bool)
            else:
                dt = t - self.t_cross_s[j]
                c = self.p0_m[j] + self.vel_mps[j] * dt[..., None]
                h = np.broadcast_to(np.arctan2(self.vel_mps[j, 1], self.vel_mps[j, 0]), dt.shape)
                act = np.abs(dt * np.hypot(*self.vel_mps[j].T)) < LINE_TRACK_HALF_LENGTH_M
            centre[:, sel], head[:, sel], active[:, sel] = c, h, act
        return centre, head, active

    def pedestrian_positions(self, drive: EgoDrive, t_s: np.ndarray, idx: np.ndarray | None = None):
        """Positions float64[T, P, 2] of pedestrians ``idx`` at times ``t_s`` float64[T]."""
        idx = np.arange(len(self.ped_s0_m)) if idx is None else np.asarray(idx)
        t = np.asarray(t_s, dtype=np.float64).reshape(-1, 1)
        s = np.clip(self.ped_s0_m[idx] + self.ped_speed_mps[idx] * t, 0.0, drive.road.length_m)
        xy, _ = drive.road.pose_at(s, self.ped_lateral_m[idx])
        return xy

    def box_segments(self, drive: EgoDrive, t_s: np.ndarray, near_m: np.ndarray, radius_m: float):
        """Segments of the boxes within ``radius_m`` of ``near_m`` at the middle time.

        Returns (a float64[T, 4N, 2], b float64[T, 4N, 2], refl_db[4N], trans_db[4N]); inactive
        boxes are collapsed to a point far away (they never intersect a ray).
        """
        t = np.asarray(t_s, dtype=np.float64)
        if not self.num_boxes:
            z = np.zeros((len(t), 0, 2))
            return z, z, np.zeros(0), np.zeros(0)
        c_mid, _, act_mid = self.box_poses(drive, t[len(t) // 2: len(t) // 2 + 1])
        near = act_mid[0] & (np.hypot(*(c_mid[0] - near_m).T) < radius_m + 15.0)
        idx = np.flatnonzero(near)
        centre, head, active = self.box_poses(drive, t, idx)
        corners = box_corners_batch(centre, head, self.length_m[idx], self.width_m[idx])
        corners[~active] = 1e9  # far away, zero length
        a = corners.reshape(len(t), -1, 2)
        b = np.roll(corners, -1, axis=2).reshape(len(t), -1, 2)
        return a, b, np.repeat(self.refl_db[idx], 4), np.repeat(self.trans_db[idx], 4)

    def pedestrian_points(self, drive: EgoDrive, t_s: np.ndarray, near_m: np.ndarray, radius_m: float):
        """(positions float64[T, P, 2], refl_db[P]) of pedestrians near ``near_m``."""
        t = np.asarray(t_s, dtype=np.float64)
        mid = self.pedestrian_positions(drive, t[len(t) // 2: len(t) // 2 + 1])[0]
        idx = np.flatnonzero(np.hypot(*(mid - near_m).T) < radius_m + 5.0)
        return self.pedestrian_positions(drive, t, idx), self.ped_refl_db[idx]


def box_corners_batch(centre: np.ndarray, head: np.ndarray, length: np.ndarray, width: np.ndarray):
    """Corners float64[..., N, 4, 2] of boxes with centres [..., N, 2], headings [..., N] and
    sizes [N] (front-left, front-right, rear-right, rear-left; long axis along the heading)."""
    c, s = np.cos(head)[..., None], np.sin(head)[..., None]
    lx = np.array([0.5, 0.5, -0.5, -0.5]) * length[:, None]
    ly = np.array([-0.5, 0.5, 0.5, -0.5]) * width[:, None]
    x = centre[..., None, 0] + c * lx - s * ly
    y = centre[..., None, 1] + s * lx + c * ly
    return np.stack([x, y], axis=-1)


def _u(rng, r, size=None):
    return rng.uniform(r[0], r[1], size=size)


def build_traffic(cfg: TrafficConfig, drive_cfg: DriveConfig, drive: EgoDrive, edge_m: float,
                  sidewalk_m: float, duration_s: float, rng: np.random.Generator) -> Traffic:
    """Populate the drive with moving objects (deterministic for a generator state).

    ``edge_m`` is the kerb's distance from the centreline, ``sidewalk_m`` the sidewalk width.
    """
    road = drive.road
    w = road.lane_width_m
    lanes = road.lanes_per_direction
    L = road.length_m
    rows = []  # (kind, s0, speed, lateral, p0x, p0y, vx, vy, t_cross, length, width, refl, trans)

    def vehicle_dims(n):
        large = rng.random(n) < cfg.large_vehicle_probability
        ln = np.where(large, _u(rng, cfg.large_vehicle_length_m, n), _u(rng, cfg.vehicle_length_m, n))
        wd = np.where(large, _u(rng, cfg.large_vehicle_width_m, n), _u(rng, cfg.vehicle_width_m, n))
        return ln, wd

    def add(kind, s0, speed, lat, ln, wd, refl, p0=None, vel=None, tc=None):
        n = len(s0)
        p0 = np.zeros((n, 2)) if p0 is None else p0
        vel = np.zeros((n, 2)) if vel is None else vel
        tc = np.zeros(n) if tc is None else tc
        trans = np.full(n, 10 * np.log10(cfg.vehicle_transmission))
        rows.append(np.column_stack([np.full(n, kind), s0, speed, lat, p0, vel, tc, ln, wd, refl, trans]))

    # oncoming: enter over the whole drive, so they keep coming
    reach = L + cfg.vehicle_speed_mps[1] * duration_s
    n = rng.poisson(cfg.oncoming_per_km * reach / 1000.0)
    ln, wd = vehicle_dims(n)
    lane = rng.integers(0, lanes, n)
    add(0, rng.uniform(0, reach, n), -_u(rng, cfg.vehicle_speed_mps, n), -lane_offset_m(lane, lanes, w), ln, wd,
        _u(rng, cfg.vehicle_reflectivity_db, n))
    # same direction, in the inner lanes the ego never uses (it keeps to lanes 0 and 1)
    ego_lanes = 2 if (drive_cfg.lane_changes_per_km > 0 and lanes >= 2) else 1
    if cfg.same_direction_per_km > 0 and lanes > ego_lanes:
        n = rng.poisson(cfg.same_direction_per_km * L / 1000.0)
        ln, wd = vehicle_dims(n)
        lane = rng.integers(ego_lanes, lanes, n)
        add(0, rng.uniform(-0.3 * L, L, n), _u(rng, cfg.vehicle_speed_mps, n), lane_offset_m(lane, lanes, w), ln, wd,
            _u(rng, cfg.vehicle_reflectivity_db, n))
    # followers on the ego's own path, at the ego's speed
    for sign, count in ((1.0, cfg.followers_ahead), (-1.0, cfg.followers_behind)):
        gap = 0.0
        for _ in range(count):
            ln, wd = vehicle_dims(1)
            gap += float(_u(rng, cfg.follower_gap_m)) + 0.5 * ln[0]
            add(1, np.array([sign * (gap + 2.5)]), np.zeros(1), np.zeros(1), ln, wd,
                _u(rng, cfg.vehicle_reflectivity_db, 1))
            gap += 0.5 * ln[0]
    # crossing traffic at intersections, timed around the ego's passage
    for s_int in road.intersections_s_m:
        k = int(np.round(_u(rng, cfg.crossing_per_intersection)))
        if not k:
            continue
        centre, tangent, normal = _intersection_frame(road, s_int)
        t_pass = float(drive.time_at_sigma(drive.sigma_of_s(s_int)))
        offs = rng.uniform(3.0, 20.0, k) * rng.choice([-1.0, 1.0], k)
        direction = rng.choice([-1.0, 1.0], k)
        speed = _u(rng, cfg.vehicle_speed_mps, k)
        ln, wd = vehicle_dims(k)
        p0 = centre + (direction * 0.5 * w)[:, None] * tangent  # keep left of the side road
        vel = (direction * speed)[:, None] * normal
        add(2, np.zeros(k), np.zeros(k), np.zeros(k), ln, wd, _u(rng, cfg.vehicle_reflectivity_db, k),
            p0=p0, vel=vel, tc=t_pass + offs)
    # cyclists: near the kerb in either direction
    n = rng.poisson(cfg.cyclists_per_km * reach / 1000.0)
    sign = rng.choice([-1.0, 1.0], n)
    add(0, rng.uniform(0, reach if n else 1, n) * 1.0, sign * _u(rng, cfg.cyclist_speed_mps, n),
        -sign * (lanes * w - 0.6), np.full(n, 1.8), np.full(n, 0.6), _u(rng, cfg.cyclist_reflectivity_db, n))
    tab = np.concatenate(rows) if rows else np.zeros((0, 13))
    # pedestrians on both sidewalks
    n_p = rng.poisson(cfg.pedestrians_per_100m * L / 100.0)
    side = rng.choice([-1.0, 1.0], n_p)
    return Traffic(
        kind=tab[:, 0].astype(np.int64), s0_m=tab[:, 1], speed_mps=tab[:, 2], lateral_m=tab[:, 3],
        p0_m=tab[:, 4:6], vel_mps=tab[:, 6:8], t_cross_s=tab[:, 8], length_m=tab[:, 9],
        width_m=tab[:, 10], refl_db=tab[:, 11], trans_db=tab[:, 12],
        ped_s0_m=rng.uniform(0, L, n_p),
        ped_speed_mps=_u(rng, cfg.pedestrian_speed_mps, n_p) * rng.choice([-1.0, 1.0], n_p),
        ped_lateral_m=side * (edge_m + rng.uniform(0.5, max(0.6, sidewalk_m - 0.3), n_p)),
        ped_refl_db=_u(rng, cfg.pedestrian_reflectivity_db, n_p),
    )


def _intersection_frame(road, s_int: float):
    """Centre, road tangent and side-road direction of an intersection. At a 90° turn the
    centre is where the incoming and outgoing centrelines cross."""
    for a, b in road.turn_spans_m:
        if a <= s_int <= b:
            pa, ha = road.pose_at(a)
            pb, hb = road.pose_at(b)
            ta = np.array([np.cos(ha), np.sin(ha)])
            tb = np.array([np.cos(hb), np.sin(hb)])
            m = np.column_stack([ta, -tb])
            u, _ = np.linalg.solve(m, pb - pa)
            return pa + u * ta, ta, tb
    p, h = road.pose_at(s_int)
    return p, np.array([np.cos(h), np.sin(h)]), np.array([-np.sin(h), np.cos(h)])
