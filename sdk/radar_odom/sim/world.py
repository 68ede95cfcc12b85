"""The static world along the road: facades, walls, fences, parked cars, poles, trees, clutter.

Everything is a line segment (surfaces that occlude: facades, walls, fences, car sides, tree
crowns as hexagons) or a point scatterer (poles, kerb stones, bushes, signs). Each carries a
reflectivity in dB and a transmission in dB (what passes through, ≤ 0). Objects are placed in
road coordinates (arc length s, lateral offset d, right = positive) along zones of three kinds:
urban blocks, corridors (continuous walls: they constrain y but not x) and open fields;
highways add guard rails with irregularly spaced posts and a median barrier. An
object that would land on a carriageway anywhere on the route (inner side of a turn, a road
crossing itself) is dropped, using a distance map of the centreline.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .config import WorldConfig
from .drive import Road

MAX_PIECE_M = 5.0  # long walls are cut into pieces so culling by distance works


@dataclass(frozen=True)
class StaticWorld:
    """Static segments and points in the world frame.

    Attributes:
        seg_a_m, seg_b_m: float64[S, 2] segment end points.
        seg_refl_db: float64[S] reflectivity; seg_trans_db: float64[S] transmission (≤ 0 dB).
        pts_m: float64[P, 2] point scatterers; pts_refl_db: float64[P].
    """

    seg_a_m: np.ndarray
    seg_b_m: np.ndarray
    seg_refl_db: np.ndarray
    seg_trans_db: np.ndarray
    pts_m: np.ndarray
    pts_refl_db: np.ndarray

    @property
    def num_segments(self) -> int:
        return len(self.seg_refl_db)

    def near(self, centre_m: np.ndarray, radius_m: float):
        """(segment mask [S], point mask [P]) of what may lie within ``radius_m`` of a point."""
        mid = 0.5 * (self.seg_a_m + self.seg_b_m)
        half = 0.5 * np.hypot(*(self.seg_b_m - self.seg_a_m).T)
        seg = np.hypot(*(mid - centre_m).T) < radius_m + half
        pts = np.hypot(*(self.pts_m - centre_m).T) < radius_m
        return seg, pts


class _Builder:
    """Collects segments and points with a per-object clearance from the carriageway."""

    def __init__(self):
        self.segs, self.seg_refl, self.seg_trans, self.seg_clear = [], [], [], []
        self.pts, self.pts_refl, self.pts_clear = [], [], []

    def polyline(self, xy: np.ndarray, refl_db: float, trans: float, clearance: float):
        if len(xy) < 2:
            return
        self.segs.append(np.concatenate([xy[:-1], xy[1:]], axis=1))
        n = len(xy) - 1
        self.seg_refl.append(np.full(n, refl_db))
        self.seg_trans.append(np.full(n, 10 * np.log10(max(trans, 1e-6))))
        self.seg_clear.append(np.full(n, clearance))

    def box(self, centre: np.ndarray, heading: float, length: float, width: float,
            refl_db: float, trans: float, clearance: float):
        self.polyline(box_corners(centre, heading, length, width, closed=True), refl_db, trans, clearance)

    def points(self, xy: np.ndarray, refl_db: np.ndarray, clearance: float):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self.pts.append(xy)
        self.pts_refl.append(np.broadcast_to(np.asarray(refl_db, dtype=np.float64), len(xy)).copy())
        self.pts_clear.append(np.full(len(xy), clearance))

    def build(self, road: Road, keep_all: bool = False) -> StaticWorld:
        segs = np.concatenate(self.segs) if self.segs else np.zeros((0, 4))
        refl = np.concatenate(self.seg_refl) if self.segs else np.zeros(0)
        trans = np.concatenate(self.seg_trans) if self.segs else np.zeros(0)
        clear = np.concatenate(self.seg_clear) if self.segs else np.zeros(0)
        segs, idx = _subdivide(segs, MAX_PIECE_M)
        refl, trans, clear = refl[idx], trans[idx], clear[idx]
        pts = np.concatenate(self.pts) if self.pts else np.zeros((0, 2))
        prefl = np.concatenate(self.pts_refl) if self.pts else np.zeros(0)
        pclear = np.concatenate(self.pts_clear) if self.pts else np.zeros(0)
        if not keep_all and (len(segs) or len(pts)):
            dist = _CentrelineDistance(road)
            a, b = segs[:, :2], segs[:, 2:]
            seg_d = np.minimum.reduce([dist(a), dist(b), dist(0.5 * (a + b))])
            keep = seg_d >= clear
            segs, refl, trans = segs[keep], refl[keep], trans[keep]
            keep_p = dist(pts) >= pclear
            pts, prefl = pts[keep_p], prefl[keep_p]
        return StaticWorld(
            seg_a_m=segs[:, :2].copy(), seg_b_m=segs[:, 2:].copy(), seg_refl_db=refl,
            seg_trans_db=trans, pts_m=pts, pts_refl_db=prefl,
        )


def box_corners(centre, heading, length, width, closed=False) -> np.ndarray:
    """float64[4 (5 if closed), 2] corners of a box (front-left, front-right, rear-right,
    rear-left) with its long axis along ``heading``."""
    c, s = np.cos(heading), np.sin(heading)
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])
    if closed:
        local = np.concatenate([local, local[:1]])
    return np.asarray(centre) + local @ np.array([[c, s], [-s, c]])


def _subdivide(segs: np.ndarray, max_len: float) -> tuple[np.ndarray, np.ndarray]:
    """Cut [S, 4] segments into pieces ≤ max_len; returns pieces and their source index."""
    if not len(segs):
        return segs, np.zeros(0, dtype=np.int64)
    length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    n = np.maximum(1, np.ceil(length / max_len).astype(np.int64))
    src = np.repeat(np.arange(len(segs)), n)
    k = np.arange(len(src)) - np.repeat(np.cumsum(n) - n, n)  # piece number within its segment
    f0 = (k / n[src])[:, None]
    f1 = ((k + 1) / n[src])[:, None]
    a, b = segs[src, :2], segs[src, 2:]
    return np.concatenate([a + (b - a) * f0, a + (b - a) * f1], axis=1), src


class _CentrelineDistance:
    """Distance (m) from any point to the road centreline, from a cv2 distance transform of
    the rasterised centreline (resolution chosen to keep the raster ≤ ~16 Mpx)."""

    def __init__(self, road: Road, margin_m: float = 250.0):
        xy = road.xy_m[:: max(1, int(1.0 / (road.s_m[1] - road.s_m[0])))]
        lo = xy.min(axis=0) - margin_m
        hi = xy.max(axis=0) + margin_m
        area = float(np.prod(hi - lo))
        self.res = max(0.5, np.sqrt(area / 16e6))
        self.lo = lo
        w, h = (np.ceil((hi - lo) / self.res)).astype(int) + 1
        img = np.full((h, w), 255, np.uint8)
        pix = np.round((xy - lo) / self.res * 16).astype(np.int32)  # 4 fractional bits
        cv2.polylines(img, [pix.reshape(-1, 1, 2)], False, 0, 1, cv2.LINE_8, shift=4)
        self.dist = cv2.distanceTransform(img, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * self.res
        self.shape = (h, w)

    def __call__(self, pts: np.ndarray) -> np.ndarray:
        if not len(pts):
            return np.zeros(0)
        ij = np.round((pts - self.lo) / self.res).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < self.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < self.shape[0])
        out = np.full(len(pts), np.inf)
        out[inside] = self.dist[ij[inside, 1], ij[inside, 0]]
        return out


def _u(rng, r, size=None):
    return rng.uniform(r[0], r[1], size=size)


def _zones(cfg: WorldConfig, length: float, rng) -> list[tuple[float, float, int]]:
    """(s0, s1, kind) stretches; kind 0 urban, 1 corridor, 2 open."""
    w = np.asarray(cfg.zone_weights, dtype=np.float64)
    w = w / w.sum()
    out, s = [], 0.0
    while s < length:
        n = float(_u(rng, cfg.zone_length_m))
        out.append((s, min(s + n, length), int(rng.choice(3, p=w))))
        s += n
    return out


def _blocked(road: Road, half_width: float) -> np.ndarray:
    """[K, 2] arc-length intervals kept free of buildings: side roads and turns."""
    iv = [(s - half_width, s + half_width) for s in road.intersections_s_m]
    iv += [(a - 6.0, b + 6.0) for a, b in road.turn_spans_m]
    return np.array(iv, dtype=np.float64).reshape(-1, 2)


def _free_runs(s0: float, s1: float, blocked: np.ndarray) -> list[tuple[float, float]]:
    """Sub-intervals of [s0, s1] outside every blocked interval."""
    runs = [(s0, s1)]
    for a, b in blocked[np.argsort(blocked[:, 0])] if len(blocked) else []:
        nxt = []
        for r0, r1 in runs:
            if b <= r0 or a >= r1:
                nxt.append((r0, r1))
                continue
            if a > r0:
                nxt.append((r0, a))
            if b < r1:
                nxt.append((b, r1))
        runs = nxt
    return [(a, b) for a, b in runs if b - a > 1.0]


def _offset_line(road: Road, s0: float, s1: float, d: float, step: float = 4.0) -> np.ndarray:
    n = max(2, int(np.ceil((s1 - s0) / step)) + 1)
    xy, _ = road.pose_at(np.linspace(s0, s1, n), d)
    return xy


def _radial_line(road: Road, s: float, d0: float, d1: float) -> np.ndarray:
    xy0, _ = road.pose_at(s, d0)
    xy1, _ = road.pose_at(s, d1)
    return np.stack([xy0, xy1])


def _urban_side(b: _Builder, cfg: WorldConfig, road: Road, runs, side: int, edge: float,
                lanes_clear: float, rng):
    """Buildings (with recesses and side walls), fences in gaps, parked cars, poles, trees."""
    front = edge + cfg.sidewalk_width_m
    for r0, r1 in runs:
        s = r0 + float(rng.uniform(0.0, cfg.building_gap_m[1]))
        while s < r1 - 4.0:
            length = min(float(_u(rng, cfg.building_length_m)), r1 - s)
            sb = front + float(_u(rng, cfg.building_setback_m))
            refl = float(_u(rng, cfg.building_reflectivity_db))
            depth = float(_u(rng, cfg.building_depth_m))
            near_junction = (s - r0 < 1.0) or (r1 - (s + length) < 1.0)
            # facade parts: a recess or bay changes the setback part-way (gives corners)
            n_parts = 1 if rng.random() > cfg.building_step_probability else int(rng.integers(2, 4))
            cuts = np.sort(rng.uniform(s, s + length, n_parts - 1)) if n_parts > 1 else np.zeros(0)
            bounds = np.concatenate([[s], cuts, [s + length]])
            ds = [sb] + [sb + float(rng.uniform(-1.5, 2.5)) for _ in range(n_parts - 1)]
            ds = [max(front + 0.3, d) for d in ds]
            for k in range(n_parts):
                b.polyline(_offset_line(road, bounds[k], bounds[k + 1], side * ds[k]), refl,
                           cfg.building_transmission, edge)
                # windows, balconies, drainpipes: point returns just in front of the facade
                n_det = rng.poisson((bounds[k + 1] - bounds[k]) / cfg.facade_detail_spacing_m)
                if n_det:
                    d_det = side * (ds[k] - rng.uniform(0.05, 0.6, n_det))
                    xy, _ = road.pose_at(rng.uniform(bounds[k], bounds[k + 1], n_det), d_det)
                    b.points(xy, refl - rng.uniform(0.0, 14.0, n_det), edge)
                if k:
                    b.polyline(_radial_line(road, bounds[k], side * ds[k - 1], side * ds[k]), refl,
                               cfg.building_transmission, edge)
            # side walls; along a side street they run deep, like its facades
            for end, d_end in ((s, ds[0]), (s + length, ds[-1])):
                deep = depth + (float(rng.uniform(15.0, 40.0)) if near_junction else 0.0)
                b.polyline(_radial_line(road, end, side * d_end, side * (d_end + deep)), refl,
                           cfg.building_transmission, edge)
            gap = float(_u(rng, cfg.building_gap_m))
            if gap > 2.0 and rng.random() < cfg.fence_probability:
                g0, g1 = s + length, min(s + length + gap, r1)
                b.polyline(_offset_line(road, g0, g1, side * (front + 0.3)),
                           float(_u(rng, cfg.fence_reflectivity_db)), cfg.fence_transmission, edge)
            s += length + gap
        span = r1 - r0
        # parked cars, in the parking lane
        n_cars = rng.poisson(cfg.parked_cars_per_100m * span / 100.0)
        for s_c in rng.uniform(r0 + 3.0, max(r0 + 3.0, r1 - 3.0), n_cars):
            ln, wd = float(rng.uniform(4.0, 4.9)), float(rng.uniform(1.7, 1.9))
            d_c = side * (edge - cfg.parking_width_m / 2 + float(rng.uniform(-0.15, 0.15)))
            xy, head = road.pose_at(s_c, d_c)
            b.box(xy, float(head) + float(rng.normal(0, 0.03)), ln, wd,
                  float(_u(rng, cfg.car_reflectivity_db)), cfg.car_transmission, lanes_clear)
        _poles_trees_kerb(b, cfg, road, r0, r1, side, edge, lanes_clear, rng, clutter_scale=1.0)


def _poles_trees_kerb(b: _Builder, cfg: WorldConfig, road: Road, r0: float, r1: float, side: int,
                      edge: float, lanes_clear: float, rng, clutter_scale: float, band_scale: float = 1.0):
    span = r1 - r0
    s = r0 + float(rng.uniform(0, cfg.pole_spacing_m[0]))
    poles = []
    while s < r1:
        poles.append(s)
        s += float(_u(rng, cfg.pole_spacing_m))
    if poles:
        xy, _ = road.pose_at(np.array(poles), side * (edge + 0.4))
        b.points(xy, _u(rng, cfg.pole_reflectivity_db, len(poles)), lanes_clear)
    n_trees = rng.poisson(cfg.trees_per_100m * span / 100.0 * clutter_scale)
    for s_t in rng.uniform(r0, r1, n_trees):
        rad = float(_u(rng, cfg.tree_radius_m))
        xy, _ = road.pose_at(s_t, side * (edge + rad + float(rng.uniform(0.3, cfg.sidewalk_width_m + 3.0))))
        ang = np.linspace(0, 2 * np.pi, 7) + rng.uniform(0, np.pi)
        hexagon = xy + rad * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        refl = float(_u(rng, cfg.tree_reflectivity_db))
        b.polyline(hexagon, refl, cfg.tree_transmission, lanes_clear)
        inner = xy + rng.normal(0, rad / 2, (6, 2))  # foliage: scattered returns inside
        b.points(inner, refl - rng.uniform(2, 8, 6), lanes_clear)
    # kerb stones / road edge: a faint dotted line
    n_kerb = int(span / 1.5)
    if n_kerb:
        xy, _ = road.pose_at(rng.uniform(r0, r1, n_kerb), side * (edge + rng.normal(0, 0.1, n_kerb)))
        b.points(xy, rng.uniform(18.0, 30.0, n_kerb), lanes_clear)
    # diffuse clutter beyond the kerb
    band = cfg.clutter_band_m * band_scale
    n_cl = rng.poisson(cfg.clutter_per_100m2 * span * band / 100.0 * clutter_scale)
    if n_cl:
        # most clutter on the sidewalk and verge in view of the road, the rest further out
        front = rng.random(n_cl) < cfg.clutter_front_fraction
        d = np.where(front, rng.uniform(0.2, cfg.sidewalk_width_m + 4.0, n_cl), rng.uniform(0.2, band, n_cl))
        xy, _ = road.pose_at(rng.uniform(r0, r1, n_cl), side * (edge + d))
        b.points(xy, _u(rng, cfg.clutter_reflectivity_db, n_cl), lanes_clear)


def _guardrail_posts(b: _Builder, cfg: WorldConfig, road: Road, d: float, clearance: float, rng):
    """Posts behind a guard rail at irregular spacing (regular posts would make the rail match
    itself every post spacing)."""
    n = int(road.length_m / cfg.guardrail_post_spacing_m[0]) + 1
    s = np.cumsum(_u(rng, cfg.guardrail_post_spacing_m, n))
    s = s[s < road.length_m]
    xy, _ = road.pose_at(s, d + np.sign(d) * 0.15)
    b.points(xy, _u(rng, cfg.guardrail_reflectivity_db, len(s)) - rng.uniform(0.0, 8.0, len(s)), clearance)


def build_world(cfg: WorldConfig, road: Road, rng: np.random.Generator) -> StaticWorld:
    """Generate the static world along ``road`` (deterministic for a given generator state)."""
    b = _Builder()
    w = road.lane_width_m
    lanes_clear = road.lanes_per_direction * w + 0.1
    edge = road.lanes_per_direction * w + cfg.parking_width_m  # kerb line
    if cfg.procedural:
        blocked = _blocked(road, edge + 4.0)
        for z0, z1, kind in _zones(cfg, road.length_m, rng):
            for side in (-1, 1):
                runs = _free_runs(z0, z1, blocked) if kind == 0 else [(z0, z1)]
                if kind == 0:
                    _urban_side(b, cfg, road, runs, side, edge, lanes_clear, rng)
                elif kind == 1:  # corridor: one continuous wall, few features
                    d = side * (edge + cfg.sidewalk_width_m + float(_u(rng, cfg.corridor_setback_m)))
                    for r0, r1 in _free_runs(z0, z1, blocked):
                        b.polyline(_offset_line(road, r0, r1, d, step=3.0),
                                   float(_u(rng, cfg.corridor_wall_reflectivity_db)),
                                   cfg.building_transmission, edge)
                    _poles_trees_kerb(b, cfg, road, z0, z1, side, edge, lanes_clear, rng,
                                      clutter_scale=cfg.open_clutter_scale, band_scale=0.2)
                else:  # open: fields with sparse posts or trees, maybe a fence
                    s = z0 + float(_u(rng, cfg.open_feature_spacing_m)) / 2
                    while s < z1:
                        xy, _ = road.pose_at(s, side * (edge + float(rng.uniform(1.0, 25.0))))
                        b.points(xy, float(_u(rng, cfg.pole_reflectivity_db)), lanes_clear)
                        s += float(_u(rng, cfg.open_feature_spacing_m))
                    if rng.random() < cfg.fence_probability:
                        b.polyline(_offset_line(road, z0, z1, side * (edge + float(rng.uniform(1.0, 5.0)))),
                                   float(_u(rng, cfg.fence_reflectivity_db)), cfg.fence_transmission, edge)
                    n_cl = rng.poisson(cfg.clutter_per_100m2 * cfg.open_clutter_scale * (z1 - z0) * 80.0 / 100.0)
                    xy, _ = road.pose_at(rng.uniform(z0, z1, n_cl), side * (edge + rng.uniform(0.2, 80.0, n_cl)))
                    b.points(xy, _u(rng, cfg.clutter_reflectivity_db, n_cl), lanes_clear)
                if cfg.noise_barrier_probability > 0 and rng.random() < cfg.noise_barrier_probability:
                    d = side * (edge + cfg.sidewalk_width_m)
                    b.polyline(_offset_line(road, z0, z1, d, step=3.0),
                               float(_u(rng, cfg.corridor_wall_reflectivity_db)),
                               cfg.building_transmission, edge)
        if cfg.guardrail:
            for side in (-1, 1):
                b.polyline(_offset_line(road, 0.0, road.length_m, side * (edge - 0.3), step=3.0),
                           float(_u(rng, cfg.guardrail_reflectivity_db)), cfg.guardrail_transmission,
                           lanes_clear)
                _guardrail_posts(b, cfg, road, side * (edge - 0.2), lanes_clear, rng)
    world = b.build(road)
    extra = _Builder()
    if cfg.procedural and cfg.median_barrier:  # on the centreline: exempt from the clearance rule
        extra.polyline(_offset_line(road, 0.0, road.length_m, 0.0, step=3.0),
                       float(_u(rng, cfg.guardrail_reflectivity_db)), cfg.guardrail_transmission, 0.0)
        s_p = np.cumsum(_u(rng, cfg.pole_spacing_m, int(road.length_m / cfg.pole_spacing_m[0]) + 1))
        s_p = s_p[s_p < road.length_m]
        xy, _ = road.pose_at(s_p, 0.0)
        extra.points(xy, _u(rng, cfg.pole_reflectivity_db, len(s_p)), 0.0)
        _guardrail_posts(extra, cfg, road, 0.3, 0.0, rng)
    for x0, y0, x1, y1, refl, trans in cfg.extra_walls:
        extra.polyline(np.array([[x0, y0], [x1, y1]], dtype=np.float64), refl, trans, 0.0)
    for x, y, refl in cfg.extra_points:
        extra.points(np.array([[x, y]]), refl, 0.0)
    return _merge(world, extra.build(road, keep_all=True))


def _merge(a: StaticWorld, b: StaticWorld) -> StaticWorld:
    return StaticWorld(
        seg_a_m=np.concatenate([a.seg_a_m, b.seg_a_m]),
        seg_b_m=np.concatenate([a.seg_b_m, b.seg_b_m]),
        seg_refl_db=np.concatenate([a.seg_refl_db, b.seg_refl_db]),
        seg_trans_db=np.concatenate([a.seg_trans_db, b.seg_trans_db]),
        pts_m=np.concatenate([a.pts_m, b.pts_m]),
        pts_refl_db=np.concatenate([a.pts_refl_db, b.pts_refl_db]),
    )
