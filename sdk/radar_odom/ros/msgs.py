"""ROS message conversion, without ROS: radar messages → `RadarScan`, estimates → odometry fields.

Everything here works on any object with the ROS field names (a rosbags message, an rclpy
message, a `types.SimpleNamespace`), so it is tested without ROS and shared by the bag reader
(`radar_odom.io.bag`), the bag writer (`radar_odom.io.bag_out`) and the ROS 2 node example
(``examples/ros2_node.py``). Nothing here imports rosbags or rclpy.

Radar messages (rows are azimuths, columns range bins, as the Navtech drivers and CFEAR's
Oxford / MulRan bags publish them):

- ``sensor_msgs/Image`` (``mono8`` / ``8UC1`` or ``mono16`` / ``16UC1``): one row per azimuth.
  The image carries no azimuth angles or times, so `PolarImageGeometry` gives them: azimuth
  ``a`` at ``azimuth_offset_rad + 2π a / A`` and at time ``t0 + a · sweep_period_s / A``, where
  ``t0`` follows from the header stamp (``stamp`` = where in the sweep the stamp lies: first
  azimuth, middle or end). This is the *azimuth-time approximation*: a real Navtech's azimuths
  are not exactly evenly spaced in time (the shared Oxford sweeps' azimuth stamps are up to 6.4 ms
  from even spacing over a 0.252 s turn), which changes the pose only through de-skew (off by
  default) and the motion prior's time step.
- ``sensor_msgs/CompressedImage`` (``png``; a lossy ``jpeg`` would change the powers): decoded
  with OpenCV, then as an Image.
- ``navtech_msgs/msg/RadarBScanMsg`` (the Navtech ROS 2 driver's B-scan, `NAVTECH_BSCAN_MSGDEF`):
  ``b_scan_img`` (``8UC1``, height = azimuth samples, width = range bins), ``encoder_values``
  (uint16, raw encoder ticks, one per row; angle = 2π · ticks / encoder size, 5600 on the
  CTS350-X / CIR-304H) and ``timestamps`` (uint64, **nanoseconds**, one per row: the driver
  writes ``ntp_seconds · 1e9 + ntp_split_seconds``). A row whose timestamp is 0 was never filled
  by the driver (a dropped azimuth) and is marked invalid.

Odometry out follows ROS REP-103/105: frames x forward, y **left**, z up. radar-odom's poses are
in the Oxford convention (x forward, y right, z down), so y and yaw change sign on the way out
(`rep103_from_oxford`), and so do the covariance's x–y and x–yaw terms (J Σ J, J = diag(1, −1, −1)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, ScanFormatError
from ..io._layout import IHDR_BYTES, PNG_SIGNATURE, read_png_header
from ..scan import MAX_SWEEP_SPAN_US, OXFORD_ENCODER_SIZE, OXFORD_RANGE_RESOLUTION_M, RadarScan

IMAGE_MSGTYPE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_MSGTYPE = "sensor_msgs/msg/CompressedImage"
NAVTECH_BSCAN_MSGTYPE = "navtech_msgs/msg/RadarBScanMsg"
#: The Navtech ROS 2 driver's B-scan message (navtech_msgs/msg/RadarBScanMsg.msg), field for field.
NAVTECH_BSCAN_MSGDEF = """\
# B Scan from one rotation of the radar, also holds the time stamp information
sensor_msgs/Image b_scan_img

# The encoder values encompassed by the b scan
uint16[] encoder_values

# The timestamps of each azimuth in the scan
uint64[] timestamps
"""
RADAR_MSGTYPES = (IMAGE_MSGTYPE, COMPRESSED_IMAGE_MSGTYPE, NAVTECH_BSCAN_MSGTYPE)
STAMP_POSITIONS = ("first", "middle", "last")
NAVTECH_SWEEP_PERIOD_S = 0.25  # 4 Hz, the CTS350-X / CIR-304H rotation
#: variance (m², rad²) written for the components 2-D odometry does not observe (z, roll, pitch)
UNOBSERVED_VARIANCE = 1.0e6

_MONO8 = ("mono8", "8uc1")
_MONO16 = ("mono16", "16uc1")


def msgtype_name(msgtype: str) -> str:
    """``sensor_msgs/Image`` and ``sensor_msgs/msg/Image`` → ``sensor_msgs/msg/Image`` (ROS 1 names
    lack the ``msg/``)."""
    parts = str(msgtype).split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return str(msgtype)


@dataclass(frozen=True)
class PolarImageGeometry:
    """What a polar ``sensor_msgs/Image`` does not say about its sweep.

    Attributes:
        range_resolution_m: metres per range bin (column); Oxford 0.0432, MulRan 0.0595.
        range_offset_m: range of column 0, metres.
        sweep_period_s: time of one turn, s; azimuth ``a`` of ``A`` is stamped
            ``t0 + a · sweep_period_s / A``.
        stamp: where in the sweep the header stamp lies: ``"first"`` azimuth (the Oxford file
            name), ``"middle"`` or ``"last"``.
        azimuth_offset_rad: angle of row 0 (rad; Oxford's first encoder count is 13 of 5600,
            0.0146 rad, which the default 0 ignores: the relative yaw is the same either way and
            the translation turns by that angle, ≈ 1.3 cm at 0.9 m).
        encoder_size: ticks per turn of a B-scan's ``encoder_values``.
    """

    range_resolution_m: float = OXFORD_RANGE_RESOLUTION_M
    range_offset_m: float = 0.0
    sweep_period_s: float = NAVTECH_SWEEP_PERIOD_S
    stamp: str = "first"
    azimuth_offset_rad: float = 0.0
    encoder_size: int = OXFORD_ENCODER_SIZE

    def __post_init__(self):
        for name in ("range_resolution_m", "sweep_period_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a number > 0, got {v!r}")
        if self.sweep_period_s > MAX_SWEEP_SPAN_US / 1e6:  # issue 51: --sweep-period-s 10 was taken
            raise ConfigError(f"sweep_period_s {self.sweep_period_s:g} s: a spinning radar turns in under "
                              f"{MAX_SWEEP_SPAN_US / 1e6:g} s (a Navtech in 0.25 s); give one turn's time in seconds")
        for name in ("range_offset_m", "azimuth_offset_rad"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
        if self.stamp not in STAMP_POSITIONS:
            raise ConfigError(f"stamp must be one of {STAMP_POSITIONS}, got {self.stamp!r}")
        if not (isinstance(self.encoder_size, int) and self.encoder_size > 0):
            raise ConfigError(f"encoder_size must be a positive integer, got {self.encoder_size!r}")


# ------------------------------------------------------------------------------ time
def stamp_ns(stamp) -> int:
    """A ``builtin_interfaces/Time`` (``sec``, ``nanosec``) or ROS 1 time (``secs``, ``nsecs``) → ns."""
    sec = getattr(stamp, "sec", None)
    if sec is None:
        sec = stamp.secs
    nsec = getattr(stamp, "nanosec", None)
    if nsec is None:
        nsec = stamp.nsecs
    return int(sec) * 1_000_000_000 + int(nsec)


def split_ns(t_ns: int) -> tuple[int, int]:
    """ns → (sec, nanosec) for a ROS time."""
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return int(sec), int(nsec)


# ------------------------------------------------------------------------------ radar messages in
def image_pixels(msg, source: str = "image") -> np.ndarray:
    """uint8[H, W] or uint16[H, W] pixels of a ``sensor_msgs/Image`` (``mono8``/``8UC1``,
    ``mono16``/``16UC1``; row padding (``step``) and byte order honoured)."""
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if enc in _MONO8:
        dtype = np.dtype(np.uint8)
    elif enc in _MONO16:
        dtype = np.dtype(">u2" if msg.is_bigendian else "<u2")
    else:
        raise ScanFormatError(
            f"{source}: image encoding {msg.encoding!r} is not a polar radar image; expected one of "
            f"{', '.join(_MONO8 + _MONO16)} (one row per azimuth, one column per range bin)")
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data.tobytes(),
                         dtype=np.uint8)
    if h < 2 or w < 2 or step < w * dtype.itemsize or data.size < step * (h - 1) + w * dtype.itemsize:
        raise ScanFormatError(
            f"{source}: image of {h}×{w} ({msg.encoding}, step {step}) holds {data.size} bytes; "
            "the message is truncated or its size fields are wrong")
    if data.size > step * h:  # sensor_msgs/Image: data holds exactly step × height bytes
        raise ScanFormatError(
            f"{source}: image of {h}×{w} ({msg.encoding}, step {step}) holds {data.size} bytes, more than "
            f"height × step = {step * h}: its size fields do not describe its data (rows would be misread)")
    rows = np.lib.stride_tricks.as_strided(data, shape=(h, w * dtype.itemsize), strides=(step, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(h, w).astype(dtype.newbyteorder("="))


def compressed_pixels(msg, source: str = "image") -> np.ndarray:
    """uint8/uint16[H, W] pixels of a ``sensor_msgs/CompressedImage`` holding a PNG (or any
    format OpenCV decodes losslessly); `ScanFormatError` when it cannot be decoded."""
    import cv2

    fmt = str(getattr(msg, "format", ""))
    buf = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data.tobytes(),
                        dtype=np.uint8)
    if buf[: len(PNG_SIGNATURE)].tobytes() == PNG_SIGNATURE:
        # the PNG files' decompression-bomb guard, from the header, before anything is decoded
        read_png_header(source, buf[:IHDR_BYTES].tobytes())
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    except cv2.error as exc:  # a header OpenCV refuses: one line, not its traceback
        raise ScanFormatError(f"{source}: compressed image (format {fmt!r}) could not be decoded: "
                              f"{str(exc).strip().splitlines()[-1][:160]}") from None
    if img is None:
        raise ScanFormatError(
            f"{source}: compressed image (format {fmt!r}, {buf.size} bytes) could not be decoded; "
            "publish the polar sweep as a PNG CompressedImage or a raw sensor_msgs/Image (mono8/mono16)")
    if img.ndim == 3:  # a grey sweep saved as colour: its channels are equal
        img = img[..., 0]
    if img.dtype not in (np.uint8, np.uint16):
        raise ScanFormatError(f"{source}: compressed image decodes to {img.dtype}; expected 8- or 16-bit grey")
    return img


def _power(pixels: np.ndarray) -> np.ndarray:
    """Pixels → power: uint8 as it is (`RadarScan.from_arrays` divides by 255, as for a PNG),
    uint16 → float32 / 65535."""
    if pixels.dtype == np.uint8:
        return pixels
    return pixels.astype(np.float32) / np.float32(65535.0)


def scan_from_polar_pixels(pixels: np.ndarray, stamp_ns_: int, geometry: PolarImageGeometry,
                           source: str = "image") -> RadarScan:
    """A `RadarScan` from polar pixels [A azimuths, B bins] stamped ``stamp_ns_`` (see
    `PolarImageGeometry` for the azimuth angles and times it assumes)."""
    a = int(pixels.shape[0])
    period_us = geometry.sweep_period_s * 1e6
    shift_us = {"first": 0.0, "middle": period_us / 2.0, "last": period_us * (a - 1) / a}[geometry.stamp]
    t0_us = stamp_ns_ / 1000.0 - shift_us
    times_us = np.round(t0_us + np.arange(a) * (period_us / a)).astype(np.int64)
    az = np.mod(geometry.azimuth_offset_rad + 2.0 * np.pi * np.arange(a) / a, 2.0 * np.pi)
    if np.any(np.diff(az) <= 0):  # an offset wraps the angles: start the sweep at the row after the wrap
        raise ScanFormatError(f"{source}: azimuth_offset_rad {geometry.azimuth_offset_rad} wraps the sweep "
                              "past 2π; give an offset in [0, 2π / azimuths)")
    return RadarScan.from_arrays(times_us, az, _power(pixels), range_resolution_m=geometry.range_resolution_m,
                                 range_offset_m=geometry.range_offset_m, source=source)


def scan_from_image_msg(msg, geometry: PolarImageGeometry = PolarImageGeometry(),
                        source: str = "image") -> RadarScan:
    """``sensor_msgs/Image`` polar sweep → `RadarScan` (module docstring)."""
    return scan_from_polar_pixels(image_pixels(msg, source), stamp_ns(msg.header.stamp), geometry, source)


def scan_from_compressed_msg(msg, geometry: PolarImageGeometry = PolarImageGeometry(),
                             source: str = "image") -> RadarScan:
    """``sensor_msgs/CompressedImage`` (PNG) polar sweep → `RadarScan`."""
    return scan_from_polar_pixels(compressed_pixels(msg, source), stamp_ns(msg.header.stamp), geometry, source)


MIN_SWEEP_SPAN_NS = 10**7  # 10 ms: a scanning radar's turn takes longer (CTS350-X 250 ms); µs read as ns: 0.25 ms


def scan_from_bscan_msg(msg, geometry: PolarImageGeometry = PolarImageGeometry(),
                        source: str = "b-scan") -> RadarScan:
    """``navtech_msgs/msg/RadarBScanMsg`` → `RadarScan` with the driver's own azimuth times and
    encoder angles (only the range resolution and offset and the encoder size come from
    ``geometry``). Rows with a zero timestamp (never filled) are invalid."""
    pixels = image_pixels(msg.b_scan_img, source)
    a = pixels.shape[0]
    enc = np.asarray(msg.encoder_values).astype(np.int64).reshape(-1)
    ts_ns = np.asarray(msg.timestamps).astype(np.uint64).reshape(-1)
    if enc.shape != (a,) or ts_ns.shape != (a,):
        raise ScanFormatError(
            f"{source}: B-scan has {a} image rows but {enc.size} encoder values and {ts_ns.size} timestamps; "
            "they must be one per row")
    valid = ts_ns > 0
    if not valid.any():
        raise ScanFormatError(f"{source}: every azimuth timestamp of the B-scan is 0; the sweep holds no data")
    if int(enc.max()) >= geometry.encoder_size:
        raise ScanFormatError(
            f"{source}: encoder value {int(enc.max())} ≥ encoder size {geometry.encoder_size}; give the radar's "
            "encoder size (its RadarConfigurationMsg.encoder_size)")
    span_ns = int(ts_ns[valid].max() - ts_ns[valid].min())
    if valid.sum() >= 10 and span_ns < MIN_SWEEP_SPAN_NS:
        raise ScanFormatError(
            f"{source}: the B-scan's azimuth timestamps span {span_ns} ns over {int(valid.sum())} rows, but a "
            f"sweep takes tens of milliseconds or more (≥ {MIN_SWEEP_SPAN_NS // 10**6} ms even at 40 Hz): they are "
            "not nanoseconds (µs?); RadarBScanMsg.timestamps must be ns")
    ts_us = (ts_ns // np.uint64(1000)).astype(np.int64)
    # a dropped row keeps a stale time and angle: give it its neighbours' spacing so the arrays stay ordered
    if not valid.all():
        idx = np.arange(a)
        ts_us = np.round(np.interp(idx, idx[valid], ts_us[valid])).astype(np.int64)
        enc = np.round(np.interp(idx, idx[valid], enc[valid])).astype(np.int64)
    az = 2.0 * np.pi * enc / geometry.encoder_size
    return RadarScan.from_arrays(ts_us, az, _power(pixels), valid=valid,
                                 range_resolution_m=geometry.range_resolution_m,
                                 range_offset_m=geometry.range_offset_m,
                                 encoder_counts=enc.astype(np.uint16), source=source)


def scan_from_msg(msg, msgtype: str, geometry: PolarImageGeometry = PolarImageGeometry(),
                  source: str = "message") -> RadarScan:
    """Any supported radar message (`RADAR_MSGTYPES`) → `RadarScan`; `ScanFormatError` for others."""
    name = msgtype_name(msgtype)
    if name == IMAGE_MSGTYPE:
        return scan_from_image_msg(msg, geometry, source)
    if name == COMPRESSED_IMAGE_MSGTYPE:
        return scan_from_compressed_msg(msg, geometry, source)
    if name == NAVTECH_BSCAN_MSGTYPE:
        return scan_from_bscan_msg(msg, geometry, source)
    raise ScanFormatError(f"{source}: message type {msgtype} is not a radar sweep radar-odom reads; "
                          f"supported: {', '.join(RADAR_MSGTYPES)}")


# ------------------------------------------------------------------------------ odometry out
def rep103_from_oxford(x_m: float, y_m: float, yaw_rad: float) -> tuple[float, float, float]:
    """(x, y, yaw) in the Oxford frame (x fwd, y right, z down) → REP-103 (x fwd, y left, z up)."""
    return float(x_m), -float(y_m), -float(yaw_rad)


def covariance_rep103(cov3_oxford) -> np.ndarray:
    """float64[3, 3] over Oxford (x, y, yaw) → the same over REP-103 (x, y, yaw): J Σ J,
    J = diag(1, −1, −1)."""
    j = np.diag([1.0, -1.0, -1.0])
    return j @ np.asarray(cov3_oxford, dtype=np.float64) @ j


def covariance_6x6(cov3) -> np.ndarray:
    """float64[36] row-major over (x, y, z, roll, pitch, yaw) from a 3×3 over (x, y, yaw);
    z, roll and pitch get `UNOBSERVED_VARIANCE` on the diagonal and no correlation."""
    out = np.zeros((6, 6))
    idx = (0, 1, 5)
    c = np.asarray(cov3, dtype=np.float64)
    for i, a in enumerate(idx):
        for k, b in enumerate(idx):
            out[a, b] = c[i, k]
    for d in (2, 3, 4):
        out[d, d] = UNOBSERVED_VARIANCE
    return out.reshape(36)


def yaw_quaternion_xyzw(yaw_rad: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of a rotation by ``yaw_rad`` about z."""
    return 0.0, 0.0, math.sin(yaw_rad / 2.0), math.cos(yaw_rad / 2.0)


@dataclass(frozen=True)
class OdometryFields:
    """One ``nav_msgs/Odometry`` in REP-103 frames, ready to copy into a message.

    Attributes:
        stamp_ns: the sweep's time, ns.
        position_m: (x, y, 0) of the base in the odom frame (the first sweep's base frame).
        orientation_xyzw: quaternion of the base in the odom frame (a yaw).
        pose_covariance: float64[36] row-major over (x, y, z, roll, pitch, yaw): this step's
            covariance, rotated into the odom frame's axes (the new pose's uncertainty given the
            previous one); `UNOBSERVED_VARIANCE` on z, roll, pitch.
        linear_mps: (vx, vy, 0) in the base frame (the step over its time: the constant-velocity
            motion the prior carries on).
        angular_rps: (0, 0, ωz).
        twist_covariance: float64[36]: the step covariance / dt², base frame.
    """

    stamp_ns: int
    position_m: tuple
    orientation_xyzw: tuple
    pose_covariance: np.ndarray
    linear_mps: tuple
    angular_rps: tuple
    twist_covariance: np.ndarray


def odometry_fields(stamp_ns_: int, pose_abs_oxford, step_pose_oxford, step_cov_oxford, dt_s: float,
                    prev_yaw_oxford_rad: float) -> OdometryFields:
    """`OdometryFields` of one estimate.

    Args:
        stamp_ns_: the sweep's time (ns).
        pose_abs_oxford: float[3, 3] the sweep's absolute pose (Oxford frame, first sweep = identity).
        step_pose_oxford: float[3] (x, y, yaw) of this sweep in the previous one (`Estimate.pose`).
        step_cov_oxford: float[3, 3] its covariance (`Estimate.covariance`).
        dt_s: time since the previous sweep (s), > 0.
        prev_yaw_oxford_rad: the previous sweep's absolute yaw (Oxford), to turn the step
            covariance into the odom frame.
    """
    from ..se2 import to_xyyaw

    x, y, yaw = rep103_from_oxford(*to_xyyaw(np.asarray(pose_abs_oxford)[None])[0])
    cov = covariance_rep103(step_cov_oxford)
    th = -float(prev_yaw_oxford_rad)  # REP-103 heading of the previous sweep
    rot = np.array([[math.cos(th), -math.sin(th), 0.0], [math.sin(th), math.cos(th), 0.0], [0.0, 0.0, 1.0]])
    pose_cov = covariance_6x6(rot @ cov @ rot.T)
    sx, sy, syaw = rep103_from_oxford(*np.asarray(step_pose_oxford, dtype=np.float64))
    if not (dt_s > 0 and math.isfinite(dt_s)):
        raise ConfigError(f"dt_s must be > 0 s, got {dt_s!r}")
    twist_cov = covariance_6x6(cov / (dt_s * dt_s))
    return OdometryFields(
        stamp_ns=int(stamp_ns_), position_m=(x, y, 0.0), orientation_xyzw=yaw_quaternion_xyzw(yaw),
        pose_covariance=pose_cov, linear_mps=(sx / dt_s, sy / dt_s, 0.0), angular_rps=(0.0, 0.0, syaw / dt_s),
        twist_covariance=twist_cov)
