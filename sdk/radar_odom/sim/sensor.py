"""Render one Navtech-style polar sweep (and its static label) from geometry.

Per sweep, vectorised:

1. Each azimuth row casts a ray from the ego pose *at that row's timestamp* (motion
   distortion), intersecting every nearby segment at once as [A, S] arrays.
2. Hits are sorted by (row, range); each hit is attenuated by the transmissions of the hits in
   front of it on its row (occlusion and shadowing); point scatterers look up the same
   cumulative attenuation. Power in dB (0 dB = receiver noise): reflectivity
   + 10·n·log10(cos incidence) - 10·k·log10(range).
3. Returns are scattered into a sparse [A, B] impulse image: single-cell returns split
   linearly between neighbouring bins and rows (sub-cell position); a surface seen at grazing
   incidence spreads along range with the beam pattern mapped onto the range it spans. Static
   returns go to one image, everything else (moving objects, multipath ghosts, phase-noise
   arcs, range sidelobes, the ego vehicle's near-range clutter) to another.
4. One separable cv2 filter applies the azimuth beam (Gaussian, FWHM = beamwidth) and the range
   main lobe to both images (stacked, with wrap-around rows for the 0/2π seam).
5. Saturation streaks raise the noise of whole rows; speckle (exponential power, one draw per
   range resolution cell) multiplies the returns and receiver noise is added; log power is
   quantised to 8 bits like a Navtech head.
6. The label is 255 where the expected static power beats everything else and the noise floor
   by the label margin.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import cv2
import numpy as np

from .config import SimConfig

DB = 10.0 / math.log(10.0)  # dB per neper of power


@dataclass(frozen=True)
class Segments:
    """Segments a→b (float64[S, 2] static, or float64[A, S, 2] one position per azimuth row),
    reflectivity dB [S], transmission dB [S] (≤ 0) and whether they move."""

    a: np.ndarray
    b: np.ndarray
    refl_db: np.ndarray
    trans_db: np.ndarray
    moving: bool


@dataclass(frozen=True)
class Points:
    """Point scatterers (float64[P, 2] static or float64[A, P, 2] per row), reflectivity dB [P]."""

    xy: np.ndarray
    refl_db: np.ndarray
    moving: bool


def _gaussian(sigma: float) -> np.ndarray:
    """Peak-normalised Gaussian kernel float32[2·ceil(3σ)+1]: an impulse keeps its peak power."""
    r = max(1, int(math.ceil(3.0 * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    return np.exp(-0.5 * (x / sigma) ** 2).astype(np.float32)


# unit-exponential quantiles at the 256 byte-value midpoints: a byte of randomness becomes an
# exponential draw through one table look-up (≈5× faster than numpy's float32 ziggurat; the
# tail is cut at 6.2× the mean, +7.9 dB, and log-power output is quantised far coarser anyway)
_EXP_LUT = (-np.log(1.0 - (np.arange(256) + 0.5) / 256.0)).astype(np.float32).reshape(1, 256)


def exponential_draws(rng: np.random.Generator, rows: int, cols: int, repeat_cols: int = 1) -> np.ndarray:
    """float32[rows, cols] unit-mean exponential power draws; with ``repeat_cols`` > 1 each draw
    covers that many neighbouring columns (speckle correlated over a resolution cell)."""
    n = -(-cols // repeat_cols)
    u = np.frombuffer(rng.bytes(rows * n), dtype=np.uint8).reshape(rows, n)
    if repeat_cols > 1:
        u = cv2.resize(u, (n * repeat_cols, rows), interpolation=cv2.INTER_NEAREST)[:, :cols]
    return cv2.LUT(np.ascontiguousarray(u), _EXP_LUT)


# standard-normal quantiles at the 256 byte-value midpoints, rescaled to unit variance: the
# same byte-to-draw look-up trick for the Gaussian fields of correlated speckle
_GAUSS_LUT = np.array([NormalDist().inv_cdf((i + 0.5) / 256.0) for i in range(256)], np.float64)
_GAUSS_LUT = (_GAUSS_LUT / _GAUSS_LUT.std()).astype(np.float32).reshape(1, 256)


def gaussian_draws(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """float32[rows, cols] unit-variance, zero-mean draws (256-level quantised Gaussian)."""
    u = np.frombuffer(rng.bytes(rows * cols), dtype=np.uint8).reshape(rows, cols)
    return cv2.LUT(np.ascontiguousarray(u), _GAUSS_LUT)


def _unit_energy_gaussian(sigma: float) -> np.ndarray:
    """Gaussian kernel with sum(k²) = 1: filtering white unit-variance noise keeps variance 1."""
    k = _gaussian(max(sigma, 1e-3)).astype(np.float64)
    return (k / np.sqrt(np.sum(k * k))).astype(np.float32)


def correlated_speckle(rng: np.random.Generator, rows: int, cols: int, sigma_rows: float,
                       sigma_bins: float) -> np.ndarray:
    """float32[rows, cols] unit-mean exponential speckle correlated along both axes.

    The real and imaginary parts of a complex white Gaussian field are each smoothed by the
    point-spread function (Gaussian, sigma in rows and bins, unit energy so the variance stays
    1); the power ``(re² + im²) / 2`` is then exponential with mean 1 at every cell, and
    neighbouring cells within the point spread share their draw, as in a real radar whose
    range FFT window and beam overlap neighbouring cells.
    """
    kr, ka = _unit_energy_gaussian(sigma_bins), _unit_energy_gaussian(sigma_rows)
    out = np.zeros((rows, cols), np.float32)
    for _ in range(2):
        g = cv2.sepFilter2D(gaussian_draws(rng, rows, cols), cv2.CV_32F, kr, ka, borderType=cv2.BORDER_REFLECT)
        out += g * g
    out *= 0.5
    return out


def azimuth_gain(rng: np.random.Generator, rows: int, std_db: float, corr_rows: float) -> np.ndarray:
    """float32[rows] linear power gain per azimuth row: a Gaussian dB sequence with std
    ``std_db``, smoothed circularly over ``corr_rows`` rows (a head's row-to-row gain wander)."""
    g = rng.standard_normal(rows + 64)
    if corr_rows > 0:
        k = _gaussian(corr_rows).astype(np.float64)
        g = np.convolve(np.concatenate([g[-len(k):], g, g[: len(k)]]), k, "same")[len(k): len(k) + rows + 64]
    g = g[:rows]
    g = (g - g.mean()) / max(g.std(), 1e-9) * std_db
    return (10.0 ** (g / 10.0)).astype(np.float32)


def ray_segment_hits(orig: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray,
                     r_min: float, r_max: float):
    """Intersect A rays with S segments.

    Args:
        orig, dirs: float64[A, 2] ray origins and unit directions.
        a, b: float64[S, 2] or [A, S, 2] segment end points.
    Returns:
        rows int64[H], cols int64[H], range_m float64[H] and |cos(incidence)| float64[H] for
        every hit with r_min < range < r_max (segments are half-open [a, b) so a polyline's
        shared vertex is hit once).
    """
    ax, ay = a[..., 0], a[..., 1]
    vx, vy = b[..., 0] - ax, b[..., 1] - ay
    ox, oy = orig[:, 0:1], orig[:, 1:2]
    dx, dy = dirs[:, 0:1], dirs[:, 1:2]
    wx, wy = ax - ox, ay - oy
    den = dx * vy - dy * vx  # cross(d, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / den
        t = (wx * vy - wy * vx) * inv
        u = (wx * dy - wy * dx) * inv
    hit = (u >= 0.0) & (u < 1.0) & (t > r_min) & (t < r_max)
    rows, cols = np.nonzero(hit)
    rng_m = t[rows, cols]
    seg_len = np.hypot(vx, vy)
    if seg_len.ndim == 2:
        cos_inc = np.abs(den[rows, cols]) / seg_len[rows, cols]
    else:
        cos_inc = np.abs(den[rows, cols]) / seg_len[cols]
    return rows, cols, rng_m, cos_inc


def candidate_rows(orig: np.ndarray, yaw: np.ndarray, az0: float, d_az: float, a: np.ndarray,
                   b: np.ndarray, near_m: float = 15.0, margin_rows: int = 2):
    """Which azimuth rows can hit which static segment: (rows int64[N], segs int64[N]).

    A segment not containing the sensor spans less than 180° of azimuth, between its end
    points' bearings. Those are taken from the sensor poses of the first, middle and last rows
    (the sensor moves and turns during the sweep), widened by ``margin_rows``; segments within
    ``near_m`` of the middle pose, where parallax is large, keep every row.
    """
    A = len(orig)
    fr = []
    for i in (0, A // 2, A - 1):
        for e in (a, b):
            rel = e - orig[i]
            fr.append((np.arctan2(rel[:, 1], rel[:, 0]) - yaw[i] - az0) / d_az)
    fr = np.array(fr)  # [6, S] fractional rows, not yet wrapped
    ref = fr[2]
    off = np.mod(fr - ref + A / 2.0, A) - A / 2.0  # relative to one end point at mid-sweep
    lo = np.floor(ref + off.min(axis=0)).astype(np.int64) - margin_rows
    hi = np.ceil(ref + off.max(axis=0)).astype(np.int64) + margin_rows
    c = orig[A // 2]
    v = b - a
    f = np.clip(np.einsum("ij,ij->i", c - a, v) / np.maximum(np.einsum("ij,ij->i", v, v), 1e-12), 0.0, 1.0)
    near = np.hypot(*(a + f[:, None] * v - c).T) < near_m
    full = near | (hi - lo + 1 >= A)
    lo[full], hi[full] = 0, A - 1
    n = hi - lo + 1
    segs = np.repeat(np.arange(len(a)), n)
    rows = np.mod(np.repeat(lo, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n), A)
    return rows, segs


def ray_pair_hits(orig: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray, rows: np.ndarray,
                  segs: np.ndarray, r_min: float, r_max: float):
    """Like `ray_segment_hits` but only for the (row, segment) pairs given (1-D arrays)."""
    o, d, p0 = orig[rows], dirs[rows], a[segs]
    v = b[segs] - p0
    w = p0 - o
    den = d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / den
        t = (w[:, 0] * v[:, 1] - w[:, 1] * v[:, 0]) * inv
        u = (w[:, 0] * d[:, 1] - w[:, 1] * d[:, 0]) * inv
    hit = np.flatnonzero((u >= 0.0) & (u < 1.0) & (t > r_min) & (t < r_max))
    cos_inc = np.abs(den[hit]) / np.hypot(v[hit, 0], v[hit, 1])
    return rows[hit], segs[hit], t[hit], cos_inc


class SweepRenderer:
    """Turns geometry into (power uint8[A, B], static label uint8[A, B]) for one `SimConfig`.

    Holds everything fixed across a drive: azimuths, kernels, noise floor per bin and the
    ego vehicle's own near-range clutter pattern (drawn once from ``rng_fixed``).
    """

    def __init__(self, cfg: SimConfig, rng_fixed: np.random.Generator):
        s = cfg.sensor
        self.cfg = cfg
        self.A, self.B, self.res = s.num_azimuths, s.num_bins, s.range_resolution_m
        self.encoder_counts = ((np.arange(self.A) * s.encoder_step) % s.encoder_size).astype(np.uint16)
        self.azimuths_rad = self.encoder_counts.astype(np.float64) * (2 * np.pi / s.encoder_size)
        self.d_az = s.encoder_step * 2 * np.pi / s.encoder_size
        self.row_offset_us = np.round(np.arange(self.A) * (s.period_us / self.A)).astype(np.int64)
        self.r_max = s.max_range_m
        sigma_rows = s.beamwidth_deg / (2.0 * math.sqrt(2.0 * math.log(2.0))) / math.degrees(self.d_az)
        self.sigma_rows = sigma_rows
        self.max_half_bins = max(1, int(s.max_range_extent_m / self.res / 2))
        self.k_az = _gaussian(sigma_rows)
        self.k_rng = _gaussian(s.range_lobe_sigma_bins)
        self.pad = len(self.k_az) // 2
        r_b = (np.arange(self.B) + 0.5) * self.res
        floor_db = s.noise_floor_db + s.noise_floor_slope_db_per_100m * r_b / 100.0
        floor_db += s.ground_clutter_db * np.exp(-r_b / s.ground_clutter_decay_m)
        noise_b = 10.0 ** (floor_db / 10.0)
        art = cfg.artefacts
        if art.enabled and art.fixed_rings > 0:  # raise the floor at a few fixed ranges
            n = art.fixed_rings
            centre = rng_fixed.uniform(*art.fixed_ring_range_m, n) / self.res
            gain = 10.0 ** (rng_fixed.uniform(*art.fixed_ring_db, n) / 10.0) - 1.0
            offset_bins = (np.arange(self.B) - centre[:, None]) / art.fixed_ring_width_bins
            bump = gain[:, None] * np.exp(-0.5 * offset_bins**2)
            noise_b = noise_b * (1.0 + bump.sum(axis=0))
        self.noise_b = noise_b.astype(np.float32)  # mean power of everything that is not a return
        nb = int(min(self.B, round(art.near_clutter_range_m / self.res)))
        if art.enabled and nb > 0:
            # the vehicle's own body and mount: fixed per drive, smooth-ish in azimuth
            row_db = np.convolve(
                rng_fixed.normal(0, art.near_clutter_spread_db, self.A + 8), np.ones(5) / 5**0.5, "valid"
            )[: self.A]
            fall = art.near_clutter_db * (1.0 - np.arange(nb) / nb) ** 1.5
            self.near = (10.0 ** ((fall[None, :] + row_db[:, None]) / 10.0)).astype(np.float32)
        else:
            self.near = np.zeros((self.A, 0), np.float32)
        ring_rows = np.arange(-art.ring_half_width_rows, art.ring_half_width_rows + 1)
        self.ring_rows = ring_rows[ring_rows != 0]
        self.ring_w = 10 ** (art.ring_relative_db / 10) * np.exp(-np.abs(self.ring_rows) / art.ring_decay_rows)
        lobe = np.arange(-art.sidelobe_half_width_bins, art.sidelobe_half_width_bins + 1)
        self.lobe_bins = lobe[np.abs(lobe) > 3]
        self.lobe_w = 10 ** (art.sidelobe_relative_db / 10) * np.exp(-np.abs(self.lobe_bins) / art.sidelobe_decay_bins)

    def _to_counts(self, total: np.ndarray) -> np.ndarray:
        """uint8[A, B] log power of linear power ``total`` (units: 0 dB = noise at near range)."""
        s = self.cfg.sensor
        if s.integer_power:
            # linear power in units of the count-0 level, floored to an integer as the head does
            n = np.floor(total * np.float32(10.0 ** (-s.floor_db / 10.0)))
            np.maximum(n, 1.0, out=n)
            logp = cv2.log(n)
            return cv2.addWeighted(logp, DB / s.db_per_count, logp, 0.0, 0.0, dtype=cv2.CV_8U)
        logp = cv2.log(total)
        return cv2.addWeighted(logp, DB / s.db_per_count, logp, 0.0, -s.floor_db / s.db_per_count, dtype=cv2.CV_8U)

    # ------------------------------------------------------------------ geometry → returns
    def _segment_returns(self, segments: list[Segments], orig, yaw, dirs, rng) -> tuple[_Returns, _Occlusion]:
        """Every ray-segment hit, sorted by (row, range), attenuated by the hits in front; and
        the cumulative attenuation along each row for point scatterers to look up."""
        s = self.cfg.sensor
        parts = []
        centre = orig[len(orig) // 2]  # float32 relative to here: ~1e-5 m over 200 m
        o32, d32 = (orig - centre).astype(np.float32), dirs.astype(np.float32)
        for seg in segments:
            if not len(seg.refl_db):
                continue
            if seg.a.ndim == 2:  # static: only the rows that can see each segment
                pr, ps = candidate_rows(orig, yaw, self.azimuths_rad[0], self.d_az, seg.a, seg.b)
                rows, cols, r, cosi = ray_pair_hits(orig, dirs, seg.a, seg.b, pr, ps, s.min_range_m, self.r_max)
            else:  # moving: few segments, each with one position per row
                a32, b32 = (seg.a - centre).astype(np.float32), (seg.b - centre).astype(np.float32)
                rows, cols, r, cosi = ray_segment_hits(o32, d32, a32, b32, s.min_range_m, self.r_max)
                r, cosi = r.astype(np.float64), cosi.astype(np.float64)
            refl = seg.refl_db + self._scintillation(rng, len(seg.refl_db))
            parts.append((rows, r, cosi, refl[cols], seg.trans_db[cols], np.full(len(rows), seg.moving)))
        if not parts:
            e = np.zeros(0)
            parts = [(np.zeros(0, np.int64), e, e, e, e, np.zeros(0, bool))]
        rows, r, cosi, refl, trans, moving = (np.concatenate(x) for x in zip(*parts))
        order = np.lexsort((r, rows))
        rows, r, cosi, refl, trans, moving = (x[order] for x in (rows, r, cosi, refl, trans, moving))
        # attenuation in front of hit i = cum[i] - cum[first hit of its row]
        occ = _Occlusion(
            keys=rows * (2.0 * self.r_max) + r,
            cum_db=np.concatenate([[0.0], np.cumsum(trans)]),
            row_start=np.searchsorted(rows, np.arange(self.A + 1)),
            key_scale=2.0 * self.r_max,
        )
        atten = occ.cum_db[:-1] - occ.cum_db[occ.row_start[rows]]
        cosc = np.clip(cosi, s.min_incidence_cos, 1.0)  # float32 casting can overshoot 1
        p_db = refl + 10.0 * s.incidence_exponent * np.log10(cosc) - 10.0 * s.range_exponent * np.log10(r) + atten
        # a grazing surface fills the range it spans within one azimuth step
        extent = np.minimum(r * self.d_az * np.sqrt(1.0 - cosc**2) / cosc, s.max_range_extent_m)
        nbins = np.maximum(1, np.rint(extent / self.res)).astype(np.int64)
        return _Returns(rows.astype(np.float64), r, p_db, moving, nbins), occ

    def _scintillation(self, rng, n: int) -> np.ndarray:
        sd = self.cfg.sensor.scintillation_db
        return rng.normal(0.0, sd, n) if (sd > 0 and self.cfg.sensor.noise) else np.zeros(n)

    def _point_returns(self, pts: Points, orig, yaw, occ: _Occlusion, rng) -> _Returns:
        """Point scatterers at a fractional row: iterate the azimuth at which each is seen (the
        sensor moves and turns while it spins), then look up the attenuation of the segment
        hits in front of it on that row."""
        A = self.A
        n = len(pts.refl_db)
        cols = np.arange(n)
        row = np.full(n, A // 2)
        for _ in range(3):
            xy = pts.xy[row, cols] if pts.moving else pts.xy
            rel = xy - orig[row]
            bearing = np.arctan2(rel[:, 1], rel[:, 0]) - yaw[row] - self.azimuths_rad[0]
            f = np.mod(bearing, 2 * np.pi) / self.d_az
            row = np.mod(np.rint(f).astype(np.int64), A)
        r = np.hypot(rel[:, 0], rel[:, 1])
        ok = (r > self.cfg.sensor.min_range_m) & (r < self.r_max)
        refl = pts.refl_db + self._scintillation(rng, n)
        f, r, row, refl = f[ok], r[ok], row[ok], refl[ok]
        atten = occ.attenuation_db(row, r)
        p_db = refl - 10.0 * self.cfg.sensor.range_exponent * np.log10(r) + atten
        return _Returns(f, r, p_db, np.full(len(r), pts.moving), np.ones(len(r), np.int64))

    def _entries(self, ret: _Returns, to_other: bool = False):
        """Impulse entries (image 0 static / 1 other, row, bin, linear power) of returns:
        single-bin returns split linearly between neighbouring bins and rows (sub-cell
        position), extended ones spread uniformly over their bins."""
        A, res = self.A, self.res
        img = np.ones(len(ret.r), np.int64) if to_other else ret.moving.astype(np.int64)
        p_lin = 10.0 ** (ret.p_db / 10.0)
        one = ret.nbins == 1
        u = ret.r[one] / res - 0.5  # bin b is centred at (b + 0.5)·res (Oxford geometry)
        b0 = np.floor(u)
        fb = u - b0
        a0 = np.floor(ret.row[one])
        fa = ret.row[one] - a0
        w = p_lin[one]
        rows = [a0, a0, a0 + 1, a0 + 1]
        bins = [b0, b0 + 1, b0, b0 + 1]
        wts = [w * (1 - fa) * (1 - fb), w * (1 - fa) * fb, w * fa * (1 - fb), w * fa * fb]
        imgs = [img[one]] * 4
        ext = ~one
        if ext.any():
            # the beam pattern mapped onto range: a Gaussian whose sigma is the beam's sigma
            # (in rows) times the range spanned per azimuth step
            sig = np.maximum(1.0, ret.nbins[ext] * (self.sigma_rows * self.cfg.sensor.extent_beam_fraction))
            half = np.minimum(np.ceil(2.5 * sig), self.max_half_bins).astype(np.int64)
            n = 2 * half + 1
            k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n + half, n)  # offset from centre
            centre = np.rint(ret.r[ext] / res - 0.5)
            peak = p_lin[ext] / (2.5066 * sig) ** self.cfg.sensor.extent_power_exponent
            rows.append(np.repeat(np.rint(ret.row[ext]), n))
            bins.append(np.repeat(centre, n) + k)
            wts.append(np.repeat(peak, n) * np.exp(-0.5 * (k / np.repeat(sig, n)) ** 2))
            imgs.append(np.repeat(img[ext], n))
        row = np.mod(np.concatenate(rows).astype(np.int64), A)
        return np.concatenate(imgs), row, np.concatenate(bins).astype(np.int64), np.concatenate(wts)

    def _artefacts(self, ret: _Returns):
        """Entries of multipath ghosts, phase-noise arcs and range sidelobes of strong returns,
        and the per-row noise raise of saturation streaks (linear power [A])."""
        art, A, res = self.cfg.artefacts, self.A, self.res
        out = []
        g = ret.p_db > art.ghost_threshold_db
        for factor, rel_db in art.ghosts if g.any() else ():
            ghost = _Returns(
                ret.row[g],
                ret.r[g] * factor,
                ret.p_db[g] + rel_db,
                ret.moving[g],
                np.maximum(1, np.rint(ret.nbins[g] * factor)).astype(np.int64),
            )
            keep = ghost.r < self.r_max
            out.append(self._entries(ghost.select(keep), to_other=True))
        row_i = np.mod(np.rint(ret.row).astype(np.int64), A)
        bin_i = np.rint(ret.r / res - 0.5).astype(np.int64)
        for thr, offs_r, offs_b, w in (
            (art.ring_threshold_db, self.ring_rows, 0, self.ring_w),
            (art.sidelobe_threshold_db, 0, self.lobe_bins, self.lobe_w),
        ):
            sel = np.flatnonzero(ret.p_db > thr)
            if not len(sel):
                continue
            m = len(w)
            p = np.repeat(10.0 ** (ret.p_db[sel] / 10.0), m) * np.tile(w, len(sel))
            rr = np.repeat(row_i[sel], m) + np.tile(np.broadcast_to(offs_r, m), len(sel))
            bb = np.repeat(bin_i[sel], m) + np.tile(np.broadcast_to(offs_b, m), len(sel))
            out.append((np.ones(len(p), np.int64), np.mod(rr, A), bb, p))
        streak = np.zeros(A)
        st = ret.p_db > art.streak_threshold_db
        if st.any():  # the strongest return of a row saturates the receiver: raise the row
            peak = np.full(A, -np.inf)
            np.maximum.at(peak, row_i[st], ret.p_db[st])
            raise_db = np.clip((peak - art.streak_threshold_db) * art.streak_db_per_db, 0.0, art.streak_max_db)
            streak = (10.0 ** (raise_db / 10.0) - 1.0) * 10.0 ** (self.cfg.sensor.noise_floor_db / 10.0)
        return out, streak

    def render(
        self,
        orig: np.ndarray,
        yaw: np.ndarray,
        segments: list[Segments],
        points: list[Points],
        rng: np.random.Generator,
    ):
        """Render one sweep.

        Args:
            orig: float64[A, 2] sensor position at each azimuth's time (world frame, m).
            yaw: float64[A] sensor heading at each azimuth's time (rad).
            segments, points: the world near the sensor.
            rng: per-sweep generator (speckle, noise, dropped rows).
        Returns:
            power uint8[A, B], label uint8[A, B] (255 = static world dominates), valid bool[A].
        """
        cfg, s = self.cfg, self.cfg.sensor
        A, B = self.A, self.B
        phi = yaw + self.azimuths_rad
        dirs = np.stack([np.cos(phi), np.sin(phi)], axis=1)

        seg_ret, occ = self._segment_returns(segments, orig, yaw, dirs, rng)
        rets = [seg_ret] + [self._point_returns(p, orig, yaw, occ, rng) for p in points if len(p.refl_db)]
        ret = _Returns.concat(rets)
        entries = [self._entries(ret)]
        streak = np.zeros(A)
        if cfg.artefacts.enabled and len(ret.r):
            more, streak = self._artefacts(ret)
            entries += more

        # scatter into the stacked impulse image [pad | static | pad][pad | other | pad]
        p = self.pad
        H = A + 2 * p
        buf = np.zeros((2 * H, B), np.float32)
        img, row, binf, wts = (np.concatenate(x) for x in zip(*entries))
        ok = (binf >= 0) & (binf < B) & (wts > 0)
        np.add.at(buf.reshape(-1), (img[ok] * H + p + row[ok]) * B + binf[ok], wts[ok].astype(np.float32))
        if self.near.shape[1]:
            buf[H + p : H + p + A, : self.near.shape[1]] += self.near
        for off in (0, H):  # wrap-around rows so the beam blurs across the 0/2π seam
            buf[off : off + p] = buf[off + A : off + A + p]
            buf[off + A + p : off + A + 2 * p] = buf[off + p : off + 2 * p]
        # the azimuth beam and the range main lobe, both images in one separable filter
        blur = cv2.sepFilter2D(buf, cv2.CV_32F, self.k_rng, self.k_az, borderType=cv2.BORDER_CONSTANT)
        static = blur[p : p + A]
        other = blur[H + p : H + p + A]

        # streaks, speckle, receiver noise, 8-bit log power
        streak32 = streak.astype(np.float32)[:, None]
        noise = self.noise_b[None, :] + streak32
        total = static + other
        if s.noise and s.speckle_sigma_bins > 0:
            # returns and receiver noise add as complex amplitudes, then one correlated speckle
            total += noise
            total *= correlated_speckle(rng, A, B, s.speckle_sigma_rows, s.speckle_sigma_bins)
        else:
            if s.noise:
                # speckle is correlated over a range resolution cell: one draw per cell
                total *= exponential_draws(rng, A, B, max(1, int(s.speckle_cell_bins)))
                noise *= exponential_draws(rng, A, B)
            total += noise
        if s.noise and s.azimuth_gain_db > 0:
            total *= azimuth_gain(rng, A, s.azimuth_gain_db, s.azimuth_gain_rows)[:, None]
        power = self._to_counts(total)

        # static label from expected (noise-free) powers; `other` is not needed afterwards
        margin = np.float32(10 ** (cfg.labels.static_margin_db / 10))
        other += streak32
        np.maximum(other, self.noise_b[None, :], out=other)
        other *= margin
        label = cv2.compare(static, other, cv2.CMP_GT)

        valid = np.ones(A, dtype=bool)
        if s.drop_azimuth_probability > 0:
            valid = rng.random(A) >= s.drop_azimuth_probability
            power[~valid] = 0
            label[~valid] = 0
        return power, label, valid


@dataclass(frozen=True)
class _Occlusion:
    """Segment hits sorted by (row, range) as keys ``row·key_scale + range`` with the running
    sum of their transmissions (dB); ``row_start[a]`` is the first hit of row a."""

    keys: np.ndarray
    cum_db: np.ndarray
    row_start: np.ndarray
    key_scale: float

    def attenuation_db(self, row: np.ndarray, range_m: np.ndarray) -> np.ndarray:
        """Total transmission (dB, ≤ 0) of the surfaces in front of ``range_m`` on ``row``."""
        j = np.searchsorted(self.keys, row * self.key_scale + range_m)
        return self.cum_db[j] - self.cum_db[self.row_start[row]]


@dataclass(frozen=True)
class _Returns:
    """Returns before rasterisation: fractional row, range (m), power (dB), moving, bins filled."""

    row: np.ndarray
    r: np.ndarray
    p_db: np.ndarray
    moving: np.ndarray
    nbins: np.ndarray

    def select(self, m) -> _Returns:
        return _Returns(self.row[m], self.r[m], self.p_db[m], self.moving[m], self.nbins[m])

    @staticmethod
    def concat(items: list[_Returns]) -> _Returns:
        return _Returns(
            *(np.concatenate([getattr(x, f) for x in items]) for f in ("row", "r", "p_db", "moving", "nbins"))
        )
