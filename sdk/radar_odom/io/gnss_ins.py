"""RADIATE GNSS/INS reference: ``GPS_IMU_Twist`` as a track, and poses at radar times.

Layout on disk::

    SEQ/GPS_IMU_Twist.txt           "Frame: NNNNNN Time: S.F" per listing (see `.radiate`)
    SEQ/GPS_IMU_Twist/NNNNNN.txt    one sample per listing

Each sample file (RADIATE SDK README, github.com/marcelsheeny/radiate_sdk, *GPS-IMU file
format*): line 1 ``latitude, longitude, altitude`` (degrees, degrees, metres); lines 2–4 the
GPS position covariance (3×3); line 5 the IMU orientation quaternion ``x, y, z, w``; line 6
the angular velocity x, y, z; line 7 the linear acceleration x, y, z (the folder is named
after a ROS Twist; only lines 1 and 5 are used here); then three covariance blocks (3×3).
The time file lists every sample twice (consecutive frame numbers, identical times, identical
files; a few are listed once, three or four times): a time is one sample, read from the first
file listed with it. Its fractions print the nanoseconds without zero padding, which
`.radiate.parse_frame_times` reads.

**Positions** are east, north, up in metres in the tangent plane at the first sample (WGS-84
geodetic → Earth-centred → local east-north-up, exact). Within 100 m of the origin this agrees
with the radii-of-curvature form ``north = (M + h0)·Δφ``, ``east = (N + h0)·cos φ0·Δλ`` (M, N
the meridional and prime-vertical radii at the origin) to a fraction of a millimetre, but that
form's error grows with the square of the distance (≈ 0.2 m at 1 km, 2 m at 3 km), this one's
does not.

**Heading: the quaternion's convention, established from the data.** On the shared drive
``radiate-2019-02-12-edinburgh`` (1434 distinct samples, 20 Hz), candidate yaws of the
quaternion were compared with the GNSS track direction ``atan2(dN, dE)`` (over ±0.25 s) on
straight stretches (heading turning under 2°/s) above 3 m/s, 398 samples. Read as ENU
(``atan2(2(wz + xy), 1 − 2(y² + z²))``, counter-clockwise from east), heading − track has
median −7.5° and interquartile range −8.0° … −7.0°: small and near-constant. Read as NED (yaw
clockwise from north, i.e. ENU yaw ``π/2 − q_yaw``) it has median +107°, interquartile range
+57° … +111°: it turns the wrong way in every bend (so does ``−q_yaw``: −33° … +21°). The ENU
reading turned by +90°, −90° or 180° (another body axis taken as forward) is as tight but
82.5°, −97.5° or 172.5° off the track; a car does not crab, so forward is the axis with the
small offset. So ``heading_rad`` is the quaternion's ENU yaw. (The angular velocity of line 6
is about a z-down axis: its z is minus the rate of that yaw, slope 1.001, correlation −0.999.)

The INS heading is still 7.5° **clockwise** of the track (an earlier measurement of the same
drive gave 7.1°, interquartile range 4.5–7.9°): a mounting offset, not the vehicle's axis.
Left in, relative poses gain a 13 % sideways component (|y| / x summed over the radar's
steps; 4 % once corrected). `estimate_heading_offset_rad` measures the offset (−0.1309 rad
= −7.50° here, interquartile range 1.03° wide; negative = heading clockwise of the track) and
`poses_at` / `relative_poses_at` take it as ``heading_offset_rad`` and use
``heading − heading_offset_rad``, which turns the heading counter-clockwise onto the track. The
offset is not constant over a whole drive (the INS re-aligns: ~1° for several seconds on the full
drive's return leg), so the reference `radar-odom run` uses follows it in time
(`heading_offset_track_rad`: a ±5 s running median over moving samples, one offset per sample).

**Clock.** The GNSS/INS clock is not the radar's: the reference for radar time t is the sample
at ``t + clock_offset_s`` (≈ +1.7 s on the shared drive, ≈ 64 s on ``radiate-fog_6_0``).
`estimate_clock_offset_s` finds it by aligning the radar's own per-sweep odometry (yaw
increment and distance per pair) with the reference's: +1.644 s on the shared drive from the
shipped cart-0.4 model's estimates (272 pairs; the yaw term alone gives 1.63 s, the distance
term alone 1.70 s; the next-best minimum ≥ 1 s away costs 3.2 times as much).

**Frames.** The track is in a z-up world (ENU); poses come out in the Oxford convention of
`radar_odom.se2` (x forward, y right, z down; a relative pose is the later frame in the earlier
one), converted as `._zup` documents: mirrored through the x–z plane, y and yaw negated. A
right turn is a positive yaw.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError, GroundTruthWarning, SequenceError
from ..se2 import invert, relative_from_absolute, se2_batch, wrap_angle
from .radiate import parse_frame_times

GNSS_DIR = "GPS_IMU_Twist"
GNSS_TIMES_FILENAME = GNSS_DIR + ".txt"
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
# the lines of a sample file the reader uses (0-based): position and orientation
_POSITION_LINE, _QUATERNION_LINE = 0, 4
# the track direction is taken over ±0.25 s: at 3 m/s a 1.5 m baseline, so centimetre GNSS
# noise moves it by well under a degree, and a 2°/s turn by under 0.5°
_DIRECTION_HALF_WINDOW_S = 0.25
# Oxford ↔ z-up: conjugation by diag(1, −1, 1) negates y and yaw (see ._zup)
_MIRROR_SIGNS = np.array([[1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, 1.0]])


@dataclass(frozen=True)
class GnssInsTrack:
    """Distinct GNSS/INS samples of a recording, in a local east-north-up frame.

    Attributes:
        times_us: int64[M] UNIX µs on the GNSS/INS clock (not the radar's), strictly increasing.
        east_m, north_m, up_m: float64[M] position in the tangent plane at the first sample.
        heading_rad: float64[M] INS yaw, counter-clockwise from east (ENU), wrapped to (−π, π];
            the INS's own axis, ≈ 7° clockwise of the track on the shared drive (see the
            module docstring and `estimate_heading_offset_rad`).
        origin_deg_m: (latitude °, longitude °, altitude m) of the first sample.
        source: the folder read.
    """

    times_us: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    up_m: np.ndarray
    heading_rad: np.ndarray
    origin_deg_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    source: str = field(default="")

    def __post_init__(self):
        m = len(self.times_us)
        arrays = (self.east_m, self.north_m, self.up_m, self.heading_rad)
        if any(np.shape(a) != (m,) for a in arrays) or np.ndim(self.times_us) != 1:
            raise ConfigError(f"{self.source or 'GnssInsTrack'}: times and positions must be 1-D of one length")
        if m < 2 or np.any(np.diff(self.times_us) <= 0):
            raise ConfigError(
                f"{self.source or 'GnssInsTrack'}: needs at least two samples with strictly increasing times"
            )

    def __len__(self) -> int:
        return len(self.times_us)

    def seconds_since_start(self) -> np.ndarray:
        """float64[M] sample times in s after the first sample (exact differences of µs)."""
        return (self.times_us - self.times_us[0]) / 1e6


# ---------------------------------------------------------------------------------- geodesy


def _ecef_m(lat_rad, lon_rad, alt_m) -> np.ndarray:
    """float64[..., 3] Earth-centred Earth-fixed position of WGS-84 geodetic coordinates."""
    s, c = np.sin(lat_rad), np.cos(lat_rad)
    n = WGS84_A_M / np.sqrt(1.0 - _WGS84_E2 * s * s)  # prime-vertical radius of curvature
    return np.stack(
        [(n + alt_m) * c * np.cos(lon_rad), (n + alt_m) * c * np.sin(lon_rad), (n * (1.0 - _WGS84_E2) + alt_m) * s],
        axis=-1,
    )


def enu_from_geodetic(lat_deg, lon_deg, alt_m, origin_deg_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(east, north, up) float64[M] metres of WGS-84 points in the tangent plane at ``origin_deg_m``.

    Args:
        lat_deg, lon_deg, alt_m: float[M] latitude, longitude (degrees) and ellipsoidal height (m).
        origin_deg_m: (latitude °, longitude °, height m) of the plane's origin.
    """
    lat0, lon0 = np.radians(origin_deg_m[0]), np.radians(origin_deg_m[1])
    d = _ecef_m(np.radians(lat_deg), np.radians(lon_deg), np.asarray(alt_m, dtype=np.float64)) - _ecef_m(
        lat0, lon0, float(origin_deg_m[2])
    )
    sl, cl, sp, cp = np.sin(lon0), np.cos(lon0), np.sin(lat0), np.cos(lat0)
    east = -sl * d[..., 0] + cl * d[..., 1]
    north = -sp * cl * d[..., 0] - sp * sl * d[..., 1] + cp * d[..., 2]
    up = cp * cl * d[..., 0] + cp * sl * d[..., 1] + sp * d[..., 2]
    return east, north, up


def quaternion_yaw_rad(q_xyzw) -> np.ndarray:
    """float64[M] yaw about z (Z-Y-X Euler) of float[M, 4] quaternions ``x, y, z, w`` (any norm)."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


# ---------------------------------------------------------------------------------- reading


def _numbers(line: str) -> list[float]:
    """The comma-separated numbers of a line (ValueError if one is not a number)."""
    return [float(v) for v in line.split(",") if v.strip()]


def _read_sample(path: Path, listed: str) -> tuple[float, ...]:
    """(lat °, lon °, alt m, qx, qy, qz, qw) of one sample file; `SequenceError` if unusable.

    ``listed`` says where the time file lists it, for messages.
    """
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise SequenceError(
            f"{path}: no such file, but {listed}; the GNSS/INS folder is incomplete — re-copy it "
            "from the RADIATE release"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{path}: cannot read the GNSS/INS sample ({exc}); {listed}") from None
    out = []
    for index, count, what in ((_POSITION_LINE, 3, "latitude, longitude, altitude"),
                               (_QUATERNION_LINE, 4, "the orientation quaternion x, y, z, w")):
        where = f"{path}, line {index + 1}"
        try:
            values = _numbers(lines[index]) if index < len(lines) else None
        except ValueError:
            values = None
        if values is None or len(values) != count or not np.all(np.isfinite(values)):
            text = repr(lines[index].strip()[:60]) if index < len(lines) else "nothing (the file ends)"
            raise SequenceError(
                f"{where}: expected {count} comma-separated numbers ({what}), got {text}; the file "
                f"is truncated or not a RADIATE GNSS/INS sample ({listed})"
            )
        out.extend(values)
    lat, lon = out[0], out[1]
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise SequenceError(f"{path}, line 1: latitude {lat}, longitude {lon} are not degrees on the Earth ({listed})")
    if lat == 0.0 and lon == 0.0:  # a receiver's placeholder without a fix; read, the track jumps thousands of km
        raise SequenceError(f"{path}, line 1: latitude and longitude are exactly 0 (a receiver without a fix writes "
                            f"that) ({listed})")
    if np.linalg.norm(out[3:7]) < 0.5:  # unit in the files; a near-zero one has no rotation
        raise SequenceError(f"{path}, line 5: quaternion {out[3:7]} is not a rotation (norm ≈ 0) ({listed})")
    return tuple(out)


def read_radiate_gnss_ins(root) -> GnssInsTrack | None:
    """The GNSS/INS track of a RADIATE sequence, or None where ``SEQ/GPS_IMU_Twist/`` is absent.

    Reads ``SEQ/GPS_IMU_Twist.txt`` (times, see `.radiate.parse_frame_times`) and one sample
    file per distinct time (the first listed). See the module docstring for the fields used
    and the frames.

    Raises:
        SequenceError: the time file missing, garbled or going backwards; a listed sample file
            missing or garbled (the message names the file and line, and the time-file line that
            lists it); fewer than two distinct samples.
    """
    root = Path(root)
    folder = root / GNSS_DIR
    if not folder.is_dir():
        return None
    times_file = root / GNSS_TIMES_FILENAME
    try:
        text = times_file.read_text()
    except FileNotFoundError:
        raise SequenceError(
            f"{times_file}: no such file; the GNSS/INS samples in {folder} carry no times without it"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{times_file}: cannot read the GNSS/INS time file ({exc})") from None
    listing = parse_frame_times(text, str(times_file), strictly_increasing=False, steps_back=True)
    stamps = np.array(listing.times_us, dtype=np.int64)
    first, notes = _forward_samples(stamps, listing, times_file)
    if len(first) < 2:
        raise SequenceError(f"{times_file}: lists {len(first)} distinct sample time(s); a track needs two or more")
    kept, samples, bad = [], [], []
    for k in first.tolist():
        try:
            samples.append(_read_sample(folder / f"{listing.frames[k]:06d}.txt",
                                        f"it is listed on line {listing.lines[k]} of {times_file}"))
            kept.append(k)
        except SequenceError as exc:  # one unreadable sample costs that sample, not the track
            bad.append(str(exc))
    if bad:
        if len(kept) < max(2, MIN_READABLE_SHARE * len(first)):
            raise SequenceError(f"{folder}: {len(bad)} of {len(first)} GNSS/INS samples cannot be read, too many "
                                f"to use the track; the first: {bad[0]}")
        notes.append(f"{len(bad)} of {len(first)} samples cannot be read and are skipped (the first: {bad[0]})")
    if notes:
        warnings.warn(f"{folder}: " + "; ".join(notes), GroundTruthWarning, stacklevel=2)
    first = np.array(kept, dtype=np.int64)
    samples = np.array(samples)
    origin = (float(samples[0, 0]), float(samples[0, 1]), float(samples[0, 2]))
    east, north, up = enu_from_geodetic(samples[:, 0], samples[:, 1], samples[:, 2], origin)
    return GnssInsTrack(
        times_us=stamps[first],
        east_m=east,
        north_m=north,
        up_m=up,
        heading_rad=quaternion_yaw_rad(samples[:, 3:7]),
        origin_deg_m=origin,
        source=str(folder),
    )


MIN_READABLE_SHARE = 0.5  # below this share of readable samples a track is not used at all


def _forward_samples(stamps: np.ndarray, listing, times_file) -> tuple[np.ndarray, list[str]]:
    """(indices of the listings that are samples, notes): a listing is a new sample when its time is
    after every earlier one. A repeated time is the same sample listed again; a clock that steps
    back (a receiver re-sync: −0.36 s once on the full shared drive) repeats time already covered,
    so the samples until the clock is past the last kept time again are dropped (what was said
    first about a time is kept), and each step back is noted once: where and by how much."""
    latest = np.maximum.accumulate(stamps)
    is_new = np.r_[True, stamps[1:] > latest[:-1]]
    notes = []
    for k in np.flatnonzero(np.r_[False, stamps[1:] < stamps[:-1]]).tolist():
        resumed = np.flatnonzero(is_new[k:])
        dropped = int(resumed[0]) if len(resumed) else len(stamps) - k
        distinct = len(np.unique(stamps[k:k + dropped]))
        notes.append(f"the clock steps back {(latest[k - 1] - stamps[k]) / 1e6:.3f} s at line {listing.lines[k]} of "
                     f"{times_file.name} (frame {listing.frames[k]}); the {distinct} sample(s) that repeat time "
                     "already covered are dropped")
    return np.flatnonzero(is_new), notes


# ---------------------------------------------------------------------------------- heading


def _gap_free(times_s: np.ndarray, lo_s: np.ndarray, hi_s: np.ndarray, max_gap_s: float) -> np.ndarray:
    """bool[N]: [lo, hi] lies inside the samples' span and crosses no gap above ``max_gap_s``."""
    big = np.r_[0, np.cumsum(np.diff(times_s) > max_gap_s)]  # big gaps before each sample
    i_lo = np.clip(np.searchsorted(times_s, lo_s, side="right") - 1, 0, len(times_s) - 1)
    i_hi = np.clip(np.searchsorted(times_s, hi_s, side="left"), 0, len(times_s) - 1)
    return (lo_s >= times_s[0]) & (hi_s <= times_s[-1]) & (big[i_hi] == big[i_lo])


def _kinematics(track: GnssInsTrack, half_window_s: float = _DIRECTION_HALF_WINDOW_S,
                     max_sample_gap_s: float = 0.5) -> dict[str, np.ndarray]:
    """Per sample, over ``t ± half_window_s``: ``speed_mps``, ``direction_rad`` (the track's
    ``atan2(dN, dE)``, ENU), ``yaw_rate_rad_s`` (of the INS heading) and ``ok`` (the window lies
    in the track and crosses no gap above ``max_sample_gap_s``); float64[M] / bool[M]."""
    t = track.seconds_since_start()
    lo, hi = t - half_window_s, t + half_window_s
    heading = np.unwrap(track.heading_rad)
    d_e = np.interp(hi, t, track.east_m) - np.interp(lo, t, track.east_m)
    d_n = np.interp(hi, t, track.north_m) - np.interp(lo, t, track.north_m)
    return {
        "speed_mps": np.hypot(d_e, d_n) / (2 * half_window_s),
        "direction_rad": np.arctan2(d_n, d_e),
        "yaw_rate_rad_s": (np.interp(hi, t, heading) - np.interp(lo, t, heading)) / (2 * half_window_s),
        "ok": _gap_free(t, lo, hi, max_sample_gap_s),
    }


def _heading_minus_track(track: GnssInsTrack, kinematics: dict, samples) -> tuple[float, np.ndarray]:
    """(circular mean c rad, ``wrap(heading − track direction − c)`` float64[n]) over ``samples``
    (a mask or indices): centred on the circular mean first, so a spread around ±π does not split
    in two; the offset is then ``c`` plus a statistic of the centred values."""
    diff = wrap_angle(track.heading_rad[samples] - kinematics["direction_rad"][samples])
    centre = float(np.arctan2(np.mean(np.sin(diff)), np.mean(np.cos(diff))))
    return centre, wrap_angle(diff - centre)


def estimate_heading_offset_rad(
    track: GnssInsTrack,
    min_speed_mps: float = 3.0,
    *,
    max_yaw_rate_rad_s: float = np.radians(2.0),
    min_samples: int = 20,
) -> tuple[float, float, int]:
    """How far the INS heading is turned from the GNSS track direction, where the car drives straight.

    The median of ``wrap(heading − track direction)`` over samples above ``min_speed_mps`` whose
    heading turns slower than ``max_yaw_rate_rad_s`` (both over ±0.25 s); a car does not crab,
    so this is the INS's mounting offset. Negative: the heading is clockwise of the track (≈ −7.5°
    on the shared drive). Pass it as ``heading_offset_rad`` to `poses_at`.

    Returns:
        (offset rad, interquartile range width rad, number of samples used).

    Raises:
        SequenceError: fewer than ``min_samples`` samples qualify (a drive without straight
            stretches at speed; lower ``min_speed_mps`` or use a longer stretch).
    """
    k = _kinematics(track)
    use = k["ok"] & (k["speed_mps"] > min_speed_mps) & (np.abs(k["yaw_rate_rad_s"]) < max_yaw_rate_rad_s)
    n = int(use.sum())
    if n < min_samples:
        raise SequenceError(
            f"{track.source or 'GNSS/INS track'}: only {n} samples lie on straight stretches above "
            f"{min_speed_mps} m/s (need {min_samples}) to compare the INS heading with the track "
            "direction; lower min_speed_mps or use a longer stretch of the drive"
        )
    centre, around = _heading_minus_track(track, k, use)
    q25, q50, q75 = np.percentile(around, [25, 50, 75])
    return float(wrap_angle(centre + q50)), float(q75 - q25), n


TRACK_OFFSET_HALF_WINDOW_S = 5.0  # the running median's half window (shared drive's data README)


def heading_offset_track_rad(track: GnssInsTrack, min_speed_mps: float = 3.0,
                             half_window_s: float = TRACK_OFFSET_HALF_WINDOW_S) -> np.ndarray:
    """float64[M]: the INS heading's offset from the GNSS track direction at each sample, followed
    in time: the median of ``wrap(heading − track direction)`` over the samples within
    ``± half_window_s`` that move faster than ``min_speed_mps`` (direction over ±0.25 s),
    interpolated in time across stretches without such samples (held at the ends).

    The INS re-aligns while driving: on the shared RADIATE drive the offset is 6–8.5° for most of
    the stretch, but elsewhere on the same drive it steps to ~1° for several seconds; one constant
    (`estimate_heading_offset_rad`) leaves up to 6° of reference heading error there. A car does
    not crab, so the track direction is the vehicle's axis wherever it moves.

    Raises:
        SequenceError: fewer than 20 samples move faster than ``min_speed_mps``.
    """
    k = _kinematics(track)
    moving = np.flatnonzero(k["ok"] & (k["speed_mps"] > min_speed_mps))
    if len(moving) < 20:
        raise SequenceError(
            f"{track.source or 'GNSS/INS track'}: only {len(moving)} samples move faster than {min_speed_mps} m/s "
            "(need 20) to follow the INS heading's offset from the track direction; use a longer stretch "
            "of the drive, or give the offset (--gt-heading-offset-deg)"
        )
    t = track.seconds_since_start()
    centre, around = _heading_minus_track(track, k, moving)
    tm = t[moving]
    lo = np.searchsorted(tm, tm - half_window_s, side="left")
    hi = np.searchsorted(tm, tm + half_window_s, side="right")
    med = np.array([np.median(around[a:b]) for a, b in zip(lo.tolist(), hi.tolist())])
    return wrap_angle(centre + np.interp(t, tm, med))


# ---------------------------------------------------------------------------------- poses


def _check_times(times_us, what: str) -> np.ndarray:
    t = np.asarray(times_us)
    if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
        raise ConfigError(f"{what} must be a 1-D integer array of UNIX µs, got {t.dtype} of shape {t.shape}")
    return t.astype(np.int64)


def _world_xyh(track: GnssInsTrack, times_us, clock_offset_s: float, heading_offset_rad,
               max_sample_gap_s: float) -> np.ndarray:
    """float64[N, 3] (east m, north m, corrected ENU heading rad) at ``times_us + clock_offset_s``;
    ``heading_offset_rad`` one offset or float64[M], one per track sample
    (`heading_offset_track_rad`).

    Linear between the two samples around each time; NaN rows outside the track or where those
    two samples are more than ``max_sample_gap_s`` apart.
    """
    q = _check_times(times_us, "times_us")
    t = track.seconds_since_start()
    # µs differences first: float seconds of a UNIX time would keep only ~0.2 µs
    q_s = (q - track.times_us[0]) / 1e6 + float(clock_offset_s)
    i = np.clip(np.searchsorted(t, q_s, side="right") - 1, 0, len(t) - 2)
    span = t[i + 1] - t[i]
    ok = (q_s >= t[0]) & (q_s <= t[-1]) & (span <= max_sample_gap_s)
    w = np.clip((q_s - t[i]) / span, 0.0, 1.0)
    offset = np.asarray(heading_offset_rad, dtype=np.float64)
    if offset.ndim and offset.shape != track.heading_rad.shape:
        raise ConfigError(f"heading_offset_rad: one offset or one per track sample ({len(track)}), "
                          f"got shape {offset.shape}")
    heading = np.unwrap(track.heading_rad - offset)  # after the offset: a per-sample one changes the steps
    out = np.stack([
        (1 - w) * v[i] + w * v[i + 1] for v in (track.east_m, track.north_m, heading)
    ], axis=-1)
    out[~ok] = np.nan
    return out


def _to_oxford(t_zup: np.ndarray) -> np.ndarray:
    """[..., 3, 3] z-up SE(2) (y left, yaw counter-clockwise) → Oxford (y right, yaw clockwise)."""
    return t_zup * _MIRROR_SIGNS


def poses_at(
    track: GnssInsTrack,
    times_us,
    clock_offset_s: float = 0.0,
    heading_offset_rad: float = 0.0,
    max_sample_gap_s: float = 0.5,
) -> np.ndarray:
    """float64[N, 3, 3] reference poses at radar times, Oxford convention, from the first known one.

    Args:
        track: the GNSS/INS track.
        times_us: int[N] radar times (UNIX µs on the radar's clock).
        clock_offset_s: the reference for radar time t is the track at ``t + clock_offset_s``.
        heading_offset_rad: the INS heading's offset from the vehicle's axis, one for the drive
            (`estimate_heading_offset_rad`) or one per track sample (`heading_offset_track_rad`);
            the heading used is ``heading − heading_offset_rad``.
        max_sample_gap_s: no pose between samples further apart than this.

    Returns:
        Pose k is the vehicle frame (x forward, y right, z down) at time k in the frame at the
        first time that has a pose (identity there; normally time 0). NaN matrices where the
        track has no pose (outside its span, in a gap); all NaN if no time has one.
    """
    xyh = _world_xyh(track, times_us, clock_offset_s, heading_offset_rad, max_sample_gap_s)
    world = se2_batch(xyh)
    known = np.isfinite(xyh).all(axis=1)
    out = np.full_like(world, np.nan)
    if known.any():
        out[known] = _to_oxford(invert(world[np.argmax(known)]) @ world[known])
    return out


def relative_poses_at(
    track: GnssInsTrack,
    times_us,
    clock_offset_s: float = 0.0,
    heading_offset_rad: float = 0.0,
    max_sample_gap_s: float = 0.5,
) -> np.ndarray:
    """float64[N−1, 3] Oxford ``(x, y, yaw)`` of time k+1 in time k (see `poses_at`); NaN rows
    where either pose is unknown."""
    # relative poses do not depend on the frame `poses_at` anchors them in
    return relative_from_absolute(poses_at(track, times_us, clock_offset_s, heading_offset_rad, max_sample_gap_s))


# ---------------------------------------------------------------------------------- clock


@dataclass(frozen=True)
class ClockOffset:
    """The GNSS/INS clock against the radar's, from `estimate_clock_offset_s`.

    Attributes:
        offset_s: the reference for radar time t is the track at ``t + offset_s``.
        cost: the alignment cost there (mean Huber loss of the normalised yaw and distance
            residuals, summed over the two; 0 = perfect).
        num_pairs: radar pairs compared there.
        search_s: (first, last) offset searched, s.
        second_best_ratio: cost of the best other local minimum at least 1 s away over ``cost``
            (inf if none): near 1 the alignment is ambiguous, several times larger it is clear.
        grid_s, grid_cost: float64[G] the coarse search (offsets and costs; NaN where too few
            pairs could be compared).
    """

    offset_s: float
    cost: float
    num_pairs: int
    search_s: tuple[float, float]
    second_best_ratio: float
    grid_s: np.ndarray = field(repr=False)
    grid_cost: np.ndarray = field(repr=False)


_COARSE_STEP_S = 0.02
_FINE_STEP_S = 0.001
_MIN_COVERAGE = 0.8  # default search: offsets where this share of the pairs lies in the track
_SECOND_MIN_AWAY_S = 1.0
_HUBER_DELTA = 1.0  # in units of the signal's spread: larger residuals count linearly
_MIN_PAIRS = 10


def _huber(r: np.ndarray) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= _HUBER_DELTA, 0.5 * a * a, _HUBER_DELTA * (a - 0.5 * _HUBER_DELTA))


def _default_search_s(track: GnssInsTrack, radar_us: np.ndarray) -> tuple[float, float]:
    """(lo, hi) offsets, s, for which ≥ 80 % of the radar pairs lie inside the track's span."""
    t0, t1 = track.times_us[0], track.times_us[-1]
    lo_each = (t0 - radar_us[:-1]) / 1e6  # pair k is inside for lo_each[k] ≤ offset ≤ hi_each[k]
    hi_each = (t1 - radar_us[1:]) / 1e6
    need = int(np.ceil(_MIN_COVERAGE * len(lo_each)))
    can = lo_each <= hi_each  # a pair longer than the track is never inside
    lo_sorted, hi_sorted = np.sort(lo_each[can]), np.sort(hi_each[can])
    # the count of pairs inside changes only at these ends; each pair counted has lo ≤ b ≤ hi
    ends = np.r_[lo_sorted, hi_sorted]
    inside = np.searchsorted(lo_sorted, ends, side="right") - np.searchsorted(hi_sorted, ends, side="left")
    ok = ends[inside >= need]
    if len(ok) == 0:
        raise SequenceError(
            f"{track.source or 'GNSS/INS track'}: the track ({(t1 - t0) / 1e6:.1f} s) is too short to hold "
            f"{_MIN_COVERAGE:.0%} of the radar's {(radar_us[-1] - radar_us[0]) / 1e6:.1f} s at any clock offset; "
            "pass search_s=(lo, hi) to search anyway"
        )
    return float(ok.min()), float(ok.max())


def _alignment_cost(track, radar_us, est_yaw, est_dist, scales, offset_s) -> tuple[float, int]:
    """(cost, pairs compared) of the radar estimates against the reference at ``offset_s``."""
    ref = relative_poses_at(track, radar_us, offset_s)
    ok = np.isfinite(ref).all(axis=1) & np.isfinite(est_yaw) & np.isfinite(est_dist)
    n = int(ok.sum())
    if n < _MIN_PAIRS:
        return float("nan"), n
    r_yaw = wrap_angle(est_yaw[ok] - ref[ok, 2]) / scales[0]
    r_dist = (est_dist[ok] - np.hypot(ref[ok, 0], ref[ok, 1])) / scales[1]
    return float(np.mean(_huber(r_yaw)) + np.mean(_huber(r_dist))), n


def _parabola_vertex(x: np.ndarray, y: np.ndarray, k: int) -> float:
    """x of the vertex of the parabola through points k−1, k, k+1 (x[k] at an end or flat)."""
    if k == 0 or k == len(x) - 1 or not np.all(np.isfinite(y[k - 1 : k + 2])):
        return float(x[k])
    denom = y[k - 1] - 2 * y[k] + y[k + 1]
    if denom <= 0:
        return float(x[k])
    step = x[k + 1] - x[k]
    return float(x[k] + 0.5 * step * (y[k - 1] - y[k + 1]) / denom)


def estimate_clock_offset_s(
    track: GnssInsTrack,
    radar_times_us,
    est_relative,
    heading_offset_rad: float = 0.0,
    search_s: tuple[float, float] | None = None,
) -> ClockOffset:
    """The offset of the GNSS/INS clock from the radar's, by aligning the radar's own odometry.

    For each candidate offset the reference relative poses at ``radar_times_us + offset`` are
    compared with the radar's per-pair estimates through what does not depend on the INS's
    heading offset or the exact axes: the yaw increment and the distance of each step (yaw
    rate and speed per sweep). Each residual is divided by the spread (standard deviation) of
    the radar's own series, so the two terms weigh alike, and scored with a Huber loss, so a
    few failed matches count linearly. Coarse grid (0.02 s), then a 1-ms grid around the best
    and a parabola through its neighbours. Pairs with a NaN estimate or reference are left out.

    Args:
        track: the GNSS/INS track.
        radar_times_us: int[N] the radar frames' times (UNIX µs, radar clock).
        est_relative: float[N−1, 3] the radar's Oxford relative poses (x, y, yaw) per pair.
        heading_offset_rad: accepted for symmetry with `relative_poses_at`; yaw increments and
            distances do not change with a constant heading offset, so neither does the result.
        search_s: (lo, hi) offsets to search, s; default every offset at which ≥ 80 % of the
            radar pairs fall inside the track (clocks can be a minute apart: ≈ 64 s on
            ``radiate-fog_6_0``).

    Raises:
        ConfigError: shapes that do not match, an empty search range.
        SequenceError: no offset where ≥ 10 pairs can be compared.
    """
    del heading_offset_rad  # see Args: the cost is invariant to it
    radar_us = _check_times(radar_times_us, "radar_times_us")
    est = np.asarray(est_relative, dtype=np.float64)
    if len(radar_us) < 2 or est.shape != (len(radar_us) - 1, 3):
        raise ConfigError(
            f"est_relative must be float[N−1, 3] for N = {len(radar_us)} radar times, got shape {est.shape}"
        )
    est_yaw, est_dist = est[:, 2], np.hypot(est[:, 0], est[:, 1])
    finite = np.isfinite(est_yaw) & np.isfinite(est_dist)
    if finite.sum() < _MIN_PAIRS:
        raise SequenceError(f"only {int(finite.sum())} radar estimates are finite; need {_MIN_PAIRS} to align clocks")
    # floors: a series that barely varies carries no timing, and must not divide by zero
    scales = (max(float(np.std(est_yaw[finite])), 1e-3), max(float(np.std(est_dist[finite])), 1e-2))
    lo, hi = _default_search_s(track, radar_us) if search_s is None else (float(search_s[0]), float(search_s[1]))
    if not (np.isfinite(lo) and np.isfinite(hi) and hi >= lo):
        raise ConfigError(f"search_s must be (lo, hi) with lo ≤ hi, got {search_s}")
    grid = np.arange(lo, hi + 0.5 * _COARSE_STEP_S, _COARSE_STEP_S)
    costs = np.array([_alignment_cost(track, radar_us, est_yaw, est_dist, scales, s)[0] for s in grid])
    if not np.isfinite(costs).any():
        raise SequenceError(
            f"{track.source or 'GNSS/INS track'}: no offset in {lo:.2f}…{hi:.2f} s lets {_MIN_PAIRS} radar pairs be "
            "compared with the track (radar times outside it, or gaps); check the recording or pass search_s"
        )
    best = int(np.nanargmin(costs))
    fine = np.arange(grid[best] - 2 * _COARSE_STEP_S, grid[best] + 2 * _COARSE_STEP_S + 0.5 * _FINE_STEP_S,
                     _FINE_STEP_S)
    fine_costs = np.array([_alignment_cost(track, radar_us, est_yaw, est_dist, scales, s)[0] for s in fine])
    k = int(np.nanargmin(fine_costs))
    offset = _parabola_vertex(fine, fine_costs, k)
    cost, n = _alignment_cost(track, radar_us, est_yaw, est_dist, scales, offset)
    return ClockOffset(
        offset_s=offset,
        cost=cost,
        num_pairs=n,
        search_s=(lo, hi),
        second_best_ratio=_second_best_ratio(grid, costs, offset, cost),
        grid_s=grid,
        grid_cost=costs,
    )


def _second_best_ratio(grid: np.ndarray, costs: np.ndarray, offset_s: float, cost: float) -> float:
    """Lowest coarse local minimum ≥ 1 s from ``offset_s``, over ``cost``; inf if none."""
    c = np.where(np.isfinite(costs), costs, np.inf)
    left = np.r_[np.inf, c[:-1]]
    right = np.r_[c[1:], np.inf]
    minima = (c <= left) & (c <= right) & np.isfinite(c) & (np.abs(grid - offset_s) >= _SECOND_MIN_AWAY_S)
    if not minima.any():
        return float("inf")
    return float(c[minima].min() / max(cost, 1e-12))
