"""Constant-velocity motion prior for `RadarOdometer` (numpy only).

Every estimate the graph gives (the *measurement*: a relative pose with its own 3×3 covariance)
is fused with a *prediction*: the previous step's velocity carried over the new time step. The
fusion is in information form, so a direction the correlation leaves unconstrained (a long
featureless corridor: huge variance along x) is carried by the prediction, while a direction it
pins down keeps the measurement.

Conventions (as everywhere in radar-odom, see `radar_odom.se2`): a relative pose is
``(x m, y m, yaw rad)`` of the later sweep's frame in the earlier one (Oxford: x forward, y right,
positive yaw turns x towards y); a velocity is ``(vx m/s, vy m/s, yaw rate rad/s)`` in the sensor
frame, i.e. a relative pose per second; covariances are float64[3, 3] over those components.

One step (`MotionPrior.update`), in order:

1. **Prediction** (`MotionPrior.predict`): ``pose_pred = v · dt``. Its covariance is the
   velocity's (``dt² · P_v``) plus a process noise for what a vehicle can do between the two
   intervals: an acceleration ``a`` acting over the time ``τ`` between the middles of the interval
   the velocity was measured over and the predicted one moves the pose by ``a · τ · dt``, so
   ``Q = diag(a_x τ dt, a_y τ dt, α τ dt)²`` (defaults: 4 m/s² along x and y, 40 °/s² in yaw;
   τ = dt for consecutive sweeps). At 4 Hz that is 0.25 m and 2.5° per step: a hard brake
   (10 m/s²: 0.63 m off the prediction, d² ≈ 5 with σ 0.1 m) or a turn that starts at once
   (0 → 25 °/s: 6.25°, d² ≈ 5 with σ 1°) stays well inside the gate below, while a +14° yaw
   step with σ 1° while driving straight (d² ≈ 24) does not. The yaw figure is a trade-off: a
   single step cannot tell an outlier from the start of a real turn of the same size, and
   30 °/s² would also gate a +9.4° jump from the predicted yaw step (an outlier that follows an
   accepted one), but then gates about 1 % of real 0 → 25 °/s turn starts (σ 1°), each losing
   its whole 6°. (The simulator's drives stay below 30 °/s yaw rate with curvature ramps of
   8 m: yaw accelerations under 20 °/s².)
2. **External odometry** (optional, `ExternalOdometry`: wheel speed and/or yaw rate) becomes a
   relative pose with a covariance over the same interval and is fused into the prediction in
   information form (plain, no taper or gate); with no prediction it is the prior on its own.
   From there on it is part of the prior: the radar measurement is gated and fused against it.
3. **Gate**: innovation ``r = m ⊖ p`` (yaw wrapped), ``d² = rᵀ (Σm + Σp)⁻¹ r``. Above
   ``gate_d2`` (χ² with 3 dof at 99.9 %: 16.27) the measurement is not physically plausible
   given the prior: a confident outlier is **not averaged in** (a Huber-style down-weighting
   would still let most of it through); the estimate is the prior with its covariance, flagged
   ``gated`` (and ``prior_dominated``), and the velocity is not updated from it. A weak
   measurement (large Σm) is never gated: it cannot be a *confident* outlier.
   *Lock-in*: a skipped step makes the next prediction looser (τ grows by the skipped interval),
   and after ``max_consecutive_gated`` gated steps in a row the next measurement that fails the
   gate is taken as it is, unfused, flagged ``prior_reset``, and the velocity restarts from it:
   a prior that has gone wrong (the vehicle really did something outside the model) can
   override the measurements for at most that many steps.
4. **Dominance taper** (`taper_information`): in the generalized eigen-directions of (Σm, Σp),
   where the measurement carries ``ρ > 1`` times the prior's information the prior's
   information is divided by ``ρ``. Plain fusion pulls such a direction by ``1/(1 + ρ)`` of
   the innovation; tapered, by ``1/(1 + ρ²)``: a measurement 9× as informative is moved by 1 %,
   not 10 % — at the start of a real manoeuvre the constant-velocity prediction is biased, and
   a well-constrained measurement must not be pulled towards it. Where the measurement is the
   weaker one (``ρ ≤ 1``) the prior counts in full. (``taper=False`` gives plain fusion.)
5. **Fusion** (`fuse`): ``Σf⁻¹ = Σm⁻¹ + Σp⁻¹``, ``μf = Σf (Σm⁻¹ μm + Σp⁻¹ μp)`` with the tapered
   prior; the fused covariance is therefore never tighter than plain fusion would make it.
6. **prior_dominated**: the prior carries at least twice the measurement's information
   (share > ``prior_dominated_share`` = 2/3) about the translation or about the rotation
   (`prior_share`). The prior's share is what the fused estimate knows beyond the measurement,
   ``1 − σf²/σm²``: for the translation, of the distance along the fused translation's
   direction (x and y share a unit, so the direction is physical; when the translation is
   within 1σ of zero, the largest share over all directions); for the rotation, of the yaw. Translation and rotation are
   judged apart, so a tightly measured yaw cannot hide a translation taken from the prior
   (a corridor while turning), and 2/3 rather than 1/2 keeps a steady drive whose measurement
   is about as informative as one step of the prior (σm ≈ a·dt²) from flickering in and out.
7. **Velocity update**: ``v = fused / dt``, ``P_v = Σf / dt²`` — the last interval's mean
   velocity (a gated step leaves it as it was).
8. **Reported covariance**: the filter's own Σf is right only if the measurements' errors were
   independent from step to step. They are not where the prior matters most: along a corridor
   successive correlation volumes share the same ridge, and their peaks fall on the true shift
   or near zero shift step after step, so the carried velocity is much less certain than Σf says
   (highway figures below). The covariance *reported* with the estimate therefore counts the
   prior's information divided by ``report_prior_scale`` (``Σr⁻¹ = Σm⁻¹ + Ip'/k``, ``Ip'`` the
   tapered prior information; a gated step reports ``k·Σp``), while the filter itself (gate,
   fusion, velocity) keeps Σf. k = 8: on the calibration drives (seeds 2500–2503, all four
   scenarios) the shipped models' fused mean d² is 4.22 / 3.97 at k = 1 (cart-0.4 / cart-0.8;
   highways 7.1 / 5.5) and 3.00 / 2.90 at k = 8 (highways 3.2 / 2.8): ``python
   benchmarks/eval_onnx.py --seeds 2500-2503 --motion-prior --report-prior-scale K …``. A larger
   k changes little more, since it then reports the measurement's own covariance where the prior
   dominates. (k = 1 reports the filter's own covariance.)

Every covariance is symmetrized and inverted through its eigenvalues with a small floor, so a
singular or near-singular covariance never gives a NaN.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..se2 import wrap_angle as _wrap_any

PRIOR_DOMINATED = "prior_dominated"
GATED = "gated"
PRIOR_RESET = "prior_reset"

#: χ² with 3 degrees of freedom at 99.9 %: the default gate on the innovation's d².
CHI2_3DOF_999 = 16.266
#: variance (m² or rad²) standing for "no information" in a component external odometry lacks.
UNKNOWN_VARIANCE = 1e4
_REL_FLOOR = 1e-12  # eigenvalue floor relative to the largest, for inverting covariances
_ABS_FLOOR = 1e-18


@dataclass(frozen=True)
class MotionPriorConfig:
    """Parameters of the constant-velocity prior (see the module docstring for their use).

    Attributes:
        accel_std_mps2: longitudinal (sensor x) acceleration std, m/s².
        lateral_accel_std_mps2: sensor-y acceleration std, m/s² (lever arm, slip, curvature).
        yaw_accel_std_rps2: yaw-rate change per second std, rad/s² (default 40 °/s²).
        gate_d2: innovation d² above which a measurement is gated (default χ²₃ 99.9 %).
        max_consecutive_gated: gated steps in a row after which a failing measurement is
            accepted unfused and restarts the velocity (``prior_reset``); ≥ 1.
        prior_dominated_share: prior's share of the fused information about the translation
            (along its direction) or the rotation above which an estimate is flagged
            ``prior_dominated`` (2/3: the prior carries twice the measurement's information).
        taper: divide the prior's information by ρ where the measurement is ρ > 1 times as
            informative (False: plain information-form fusion).
        report_prior_scale: the reported covariance counts the prior's information divided by
            this (step 8 of the module docstring); 1 reports the filter's own covariance.
    """

    accel_std_mps2: float = 4.0
    lateral_accel_std_mps2: float = 4.0
    yaw_accel_std_rps2: float = float(np.deg2rad(40.0))
    gate_d2: float = CHI2_3DOF_999
    max_consecutive_gated: int = 2
    prior_dominated_share: float = 2.0 / 3.0
    taper: bool = True
    report_prior_scale: float = 8.0  # module docstring, step 8: measured, not fitted per model

    def __post_init__(self):
        for name in ("accel_std_mps2", "lateral_accel_std_mps2", "yaw_accel_std_rps2", "gate_d2",
                     "report_prior_scale"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"MotionPriorConfig.{name} must be a positive number, got {v!r}")
        if int(self.max_consecutive_gated) < 1:
            raise ValueError("MotionPriorConfig.max_consecutive_gated must be >= 1, "
                             f"got {self.max_consecutive_gated!r}")
        if self.report_prior_scale < 1.0:
            raise ValueError("MotionPriorConfig.report_prior_scale must be >= 1 (the filter's own covariance), "
                             f"got {self.report_prior_scale!r}")
        if not 0.0 < self.prior_dominated_share < 1.0:
            raise ValueError("MotionPriorConfig.prior_dominated_share must be in (0, 1), "
                             f"got {self.prior_dominated_share!r}")

    def process_noise(self, dt_s: float, tau_s: float) -> np.ndarray:
        """float64[3, 3] ``Q``: pose covariance of accelerations acting for ``tau_s`` over ``dt_s``."""
        s = np.array([self.accel_std_mps2, self.lateral_accel_std_mps2, self.yaw_accel_std_rps2])
        return np.diag((s * float(tau_s) * float(dt_s)) ** 2)


#: default 1σ of an external speed, as a fraction of the speed (a wheel speed's scale error)
SPEED_STD_FRACTION = 0.10
#: and its floor, m/s (standing still, creeping)
SPEED_STD_FLOOR_MPS = 0.1


@dataclass(frozen=True)
class ExternalOdometry:
    """Per-sweep odometry from another sensor (wheel speed, IMU yaw rate), for `RadarOdometer.step`.

    Both values are means over the interval from the previous sweep to this one, in the radar's
    frame: ``speed_mps`` along its x (forward) axis, ``yaw_rate_rps`` about its z axis, which
    points *down* (Oxford frame): positive turns x towards y, i.e. to the right. A z-up IMU
    reports the opposite sign — negate it. Either may be None (that component then carries no
    information). The motion is taken as a circular arc without side slip; side slip and lever
    arm are covered by ``lateral_std_mps``.

    Attributes:
        speed_mps: forward speed, m/s, or None.
        yaw_rate_rps: yaw rate, rad/s (positive: turning right), or None.
        speed_std_mps: 1σ of the speed, m/s; None (default): `SPEED_STD_FRACTION` of the speed,
            at least `SPEED_STD_FLOOR_MPS` (`speed_std`). A wheel speed is a scale error first
            (tyre radius, load, slip, a CAN speed rounded for the dashboard): measured against a
            GNSS track, one is easily 10 % off, and a fixed 0.1 m/s called a 14 % error at 11 m/s a
            16σ outlier, so the χ² gate threw out a sharp radar match (σ 2.4 cm) and kept the wheel
            speed. With the default a wheel speed 14 % off is ≈ 1.4σ, the match is not gated and,
            being far sharper, carries the fused pose (test_motion_prior measures this case).
        yaw_rate_std_rps: 1σ of the yaw rate, rad/s.
        lateral_std_mps: 1σ of the sideways velocity the arc model leaves out, m/s.
    """

    speed_mps: float | None = None
    yaw_rate_rps: float | None = None
    speed_std_mps: float | None = None
    yaw_rate_std_rps: float = float(np.deg2rad(0.5))
    lateral_std_mps: float = 0.2

    def __post_init__(self):
        from ..errors import ConfigError

        if self.speed_mps is None and self.yaw_rate_rps is None:
            raise ConfigError("ExternalOdometry needs speed_mps, yaw_rate_rps or both")
        for name in ("speed_mps", "yaw_rate_rps", "speed_std_mps", "yaw_rate_std_rps", "lateral_std_mps"):
            v = getattr(self, name)
            if v is None and name in ("speed_mps", "yaw_rate_rps", "speed_std_mps"):
                continue
            # a string ('11', from a CSV or CAN decoder) reached np.isfinite as a raw numpy TypeError
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ConfigError(f"ExternalOdometry.{name} must be a number (float), got {type(v).__name__} {v!r}; "
                                  "convert it first, e.g. float(value)")
            if not np.isfinite(v):
                raise ConfigError(f"ExternalOdometry.{name} must be finite, got {v!r}")
            if name not in ("speed_mps", "yaw_rate_rps") and not v > 0:
                raise ConfigError(f"ExternalOdometry.{name} must be a positive number, got {v!r}")

    @property
    def speed_std(self) -> float:
        """The speed's 1σ in use (m/s): ``speed_std_mps``, or by default `SPEED_STD_FRACTION` ×
        |speed|, at least `SPEED_STD_FLOOR_MPS`."""
        if self.speed_std_mps is not None:
            return float(self.speed_std_mps)
        return max(SPEED_STD_FLOOR_MPS, SPEED_STD_FRACTION * abs(float(self.speed_mps or 0.0)))

    @classmethod
    def coerce(cls, value) -> ExternalOdometry | None:
        """None, an `ExternalOdometry`, or a dict of its fields → `ExternalOdometry` (or None)."""
        if value is None or isinstance(value, cls):
            return value
        if isinstance(value, dict):
            return cls(**value)
        raise TypeError(f"odometry must be an ExternalOdometry or a dict of its fields, got {type(value).__name__}")

    def relative_pose(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(pose float64[3], covariance float64[3, 3]) of the motion over ``dt_s`` seconds.

        Arc of radius v/ω: ``x = v sin(ωdt)/ω``, ``y = v (1 − cos(ωdt))/ω``, ``yaw = ω dt``;
        the covariance is the first-order propagation of the speed and yaw-rate variances plus
        ``(lateral_std · dt)²`` on y. A missing component has `UNKNOWN_VARIANCE`.
        """
        dt = float(dt_s)
        v = 0.0 if self.speed_mps is None else float(self.speed_mps)
        w = 0.0 if self.yaw_rate_rps is None else float(self.yaw_rate_rps)
        th = w * dt
        # sin(th)/th and (1 − cos th)/th, and their derivatives, stable near th = 0
        if abs(th) < 1e-4:
            s, c = 1.0 - th * th / 6.0, th / 2.0 - th**3 / 24.0
            ds, dc = -th / 3.0, 0.5 - th * th / 8.0
        else:
            s, c = np.sin(th) / th, (1.0 - np.cos(th)) / th
            ds = (th * np.cos(th) - np.sin(th)) / th**2
            dc = (th * np.sin(th) - (1.0 - np.cos(th))) / th**2
        pose = np.array([v * dt * s, v * dt * c, th])
        # Jacobian wrt (v, ω): d/dω = d/dth · dt
        j = np.array([[dt * s, v * dt * ds * dt], [dt * c, v * dt * dc * dt], [0.0, dt]])
        var_v = UNKNOWN_VARIANCE / max(dt * dt, 1e-12) if self.speed_mps is None else self.speed_std**2
        var_w = UNKNOWN_VARIANCE / max(dt * dt, 1e-12) if self.yaw_rate_rps is None else self.yaw_rate_std_rps**2
        cov = j @ np.diag([var_v, var_w]) @ j.T
        cov[1, 1] += (self.lateral_std_mps * dt) ** 2
        if self.speed_mps is None:  # x, y unknown: no information from the arc either way
            cov[:2, :2] = np.diag([UNKNOWN_VARIANCE, UNKNOWN_VARIANCE])
            cov[:2, 2] = cov[2, :2] = 0.0
        return pose, _sym(cov)


@dataclass(frozen=True)
class PriorStep:
    """What `MotionPrior.update` did with one measurement.

    Attributes:
        pose: float64[3] the estimate (fused, the prior when gated, the measurement otherwise).
        covariance: float64[3, 3] its reported covariance (module docstring, step 8).
        filter_covariance: float64[3, 3] the filter's own (plain information form), or None when
            the two are the same (no prior, ``report_prior_scale`` = 1).
        flags: subset of {``prior_dominated``, ``gated``, ``prior_reset``}.
        d2: innovation d² against the prior (None without a prior).
        prior_share: the prior's larger share of the information about translation or
            rotation (see `prior_share`; 0 without a prior, 1 when gated).
        prior: (pose, covariance) the measurement was fused with (prediction ⊕ odometry), or None.
    """

    pose: np.ndarray
    covariance: np.ndarray
    flags: frozenset = field(default_factory=frozenset)
    d2: float | None = None
    prior_share: float = 0.0
    prior: tuple | None = None
    filter_covariance: np.ndarray | None = None


# --------------------------------------------------------------------------- linear algebra
def wrap_angle(a: float) -> float:
    """An angle wrapped to (−π, π]; one already there is returned unchanged (bit for bit)."""
    a = float(a)
    return a if -np.pi < a <= np.pi else float(_wrap_any(a))


def _sym(c) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    if c.ndim != 2:
        c = c.reshape(3, 3)
    return 0.5 * (c + c.T)


def _eig_floor(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (floored, so strictly positive) and eigenvectors of a symmetric matrix."""
    w, u = np.linalg.eigh(_sym(c))
    floor = max(_ABS_FLOOR, _REL_FLOOR * float(np.max(np.abs(w))))
    return np.maximum(w, floor), u


def inv_psd(c) -> np.ndarray:
    """Inverse of a symmetric PSD matrix ([3, 3] or [2, 2]), eigenvalues floored (never inf or NaN)."""
    w, u = _eig_floor(c)
    return _sym((u / w) @ u.T)


def _check(name, x, shape):
    a = np.asarray(x, dtype=np.float64)
    if a.shape != shape:
        a = a.reshape(shape)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} is not finite: {a.tolist()}")
    return a


def innovation(measurement, prediction) -> np.ndarray:
    """float64[3] ``measurement − prediction`` with the yaw difference wrapped to (−π, π]."""
    r = np.asarray(measurement, dtype=np.float64) - np.asarray(prediction, dtype=np.float64)
    r[2] = wrap_angle(r[2])
    return r


def mahalanobis_d2(r, cov) -> float:
    """``rᵀ cov⁻¹ r`` for float[3] ``r`` and a 3×3 covariance."""
    r = np.asarray(r, dtype=np.float64)
    return float(r @ inv_psd(cov) @ r)


def fuse(measurement, meas_cov, pred, pred_cov) -> tuple[np.ndarray, np.ndarray, dict]:
    """Information-form fusion of two estimates of one relative pose.

    ``Σf⁻¹ = Σm⁻¹ + Σp⁻¹``, ``μf = Σf (Σm⁻¹ μm + Σp⁻¹ μp)``, with the prediction's yaw first
    moved onto the measurement's branch (so 179° and −179° fuse to ±180°, not 0°).

    Args:
        measurement: float[3] (x m, y m, yaw rad).
        meas_cov: float[3, 3] its covariance.
        pred: float[3] the other estimate (the prediction).
        pred_cov: float[3, 3] its covariance.
    Returns:
        (fused float64[3] with yaw in (−π, π], fused covariance float64[3, 3] symmetric PSD,
        info dict: ``innovation`` float64[3] = measurement ⊖ pred, ``d2`` its Mahalanobis d²
        under Σm + Σp, ``translation_share`` and ``rotation_share`` the pred's share of the
        fused information about translation and rotation (see `prior_share`), and
        ``prior_share`` the larger of the two).
    """
    cp = _sym(_check("prediction covariance", pred_cov, (3, 3)))
    return fuse_information(measurement, meas_cov, pred, inv_psd(cp), d2_cov=cp)


def fuse_information(measurement, meas_cov, pred, pred_info, d2_cov=None) -> tuple[np.ndarray, np.ndarray, dict]:
    """`fuse` with the prediction given by its information matrix ``pred_info`` (= Σp⁻¹, which
    may be singular: a direction the prediction knows nothing about has zero information).

    ``d2_cov``: the prediction covariance to compute the innovation's d² with (default: from
    ``pred_info``).
    """
    m = _check("measurement", measurement, (3,))
    p = _check("prediction", pred, (3,))
    cm = _sym(_check("measurement covariance", meas_cov, (3, 3)))
    ip = _sym(_check("prediction information", pred_info, (3, 3)))
    r = innovation(m, p)
    p_branch = m - r  # the prediction, yaw on the measurement's branch
    cf = inv_psd(inv_psd(cm) + ip)
    # μf = Σf (Im m + Ip p) = m + Σf Ip (p − m): the second form keeps precision when Im ≫ Ip
    f = m + cf @ (ip @ (p_branch - m))
    f[2] = wrap_angle(f[2])
    share_t, share_r = prior_share(f, cm, cf)
    cp = inv_psd(ip) if d2_cov is None else _sym(d2_cov)
    info = {"innovation": r, "d2": mahalanobis_d2(r, cm + cp), "translation_share": share_t,
            "rotation_share": share_r, "prior_share": max(share_t, share_r)}
    return f, cf, info


def prior_share(motion, meas_cov, fused_cov) -> tuple[float, float]:
    """(translation share, rotation share) of the prior in the fused estimate.

    The prior's share is what the fused estimate knows beyond the measurement: ``1 − σf²/σm²``
    for the marginal variances of one quantity. Translation: the distance travelled along the
    fused translation's direction ``u = t/|t|`` (x and y are both metres, so the direction is
    physical): ``1 − uᵀΣf_xy u / uᵀΣm_xy u``. When ``t`` is within 1σ of zero (no direction to
    speak of) the largest share over all directions is returned instead. Rotation: the yaw's
    ``1 − σf²/σm²``. Only the measurement's and the fused covariance are needed, both well
    conditioned (the prior's may not be).
    """
    t = np.asarray(motion, dtype=np.float64)[:2]
    cm, cf = _sym(meas_cov), _sym(fused_cov)
    cm_t, cf_t = cm[:2, :2], cf[:2, :2]
    if float(t @ inv_psd(cf_t) @ t) >= 1.0:
        u = t / np.linalg.norm(t)
        share_t = 1.0 - float(u @ cf_t @ u) / max(float(u @ cm_t @ u), _ABS_FLOOR)
    else:  # max over u of 1 − uᵀΣf u / uᵀΣm u: 1 − smallest eigenvalue of Σm^-½ Σf Σm^-½
        w, v = _eig_floor(cm_t)
        h = (v / np.sqrt(w)) @ v.T
        share_t = 1.0 - float(np.linalg.eigvalsh(_sym(h @ cf_t @ h)).min())
    share_r = 1.0 - cf[2, 2] / max(cm[2, 2], _ABS_FLOOR)
    return float(np.clip(share_t, 0.0, 1.0)), float(np.clip(share_r, 0.0, 1.0))


def taper_information(meas_cov, pred_info) -> np.ndarray:
    """float64[3, 3] the prediction's information divided by ρ in each direction where the
    measurement is ρ > 1 times as informative (generalized eigen-directions of the pair).

    In the measurement-whitened frame (``Σm^½ Ip Σm^½ = V diag(β) Vᵀ``, β = 1/ρ the prior's
    information relative to the measurement's), β < 1 becomes β²; directions where the
    measurement is the weaker one keep the prior's information as it is. Works on information
    (the measurement covariance is well conditioned, the prior's may not be).
    """
    wm, um = _eig_floor(_sym(meas_cov))
    half = (um * np.sqrt(wm)) @ um.T  # Σm^½
    half_inv = (um / np.sqrt(wm)) @ um.T
    beta, v = np.linalg.eigh(_sym(half @ _sym(pred_info) @ half))
    beta = np.maximum(beta, 0.0)
    beta = np.where(beta < 1.0, beta * beta, beta)
    return _sym(half_inv @ (v * beta) @ v.T @ half_inv)


def taper_prior(meas_cov, pred_cov) -> np.ndarray:
    """float64[3, 3] the prediction covariance after `taper_information` (for inspection)."""
    return inv_psd(taper_information(meas_cov, inv_psd(pred_cov)))


def compose(a, cov_a, b, cov_b) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose ``a ∘ b`` (b expressed in a's end frame) and its first-order covariance."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[2]), np.sin(a[2])
    out = np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2])])
    ja = np.array([[1.0, 0.0, -s * b[0] - c * b[1]], [0.0, 1.0, c * b[0] - s * b[1]], [0.0, 0.0, 1.0]])
    jb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return out, _sym(ja @ _sym(cov_a) @ ja.T + jb @ _sym(cov_b) @ jb.T)


# --------------------------------------------------------------------------- the prior
class MotionPrior:
    """Constant-velocity prior: the last velocity, its covariance, and the gating state.

    Attributes:
        config: `MotionPriorConfig`.
        velocity: float64[3] (vx m/s, vy m/s, yaw rate rad/s) in the sensor frame, or None
            before the first measurement of a stream.
        velocity_covariance: float64[3, 3] over those, or None.
        interval_s: length of the interval the velocity was measured over, s.
        consecutive_gated: gated steps in a row so far.
    """

    def __init__(self, config: MotionPriorConfig | None = None):
        self.config = config or MotionPriorConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the velocity and the gating state (a new stream)."""
        # the velocity is kept as the pose over its interval (so that a prediction over an equal
        # interval is that pose exactly, bit for bit)
        self._pose: np.ndarray | None = None
        self._cov: np.ndarray | None = None
        self.interval_s = 0.0
        self.consecutive_gated = 0

    @property
    def ready(self) -> bool:
        """Whether there is a velocity to predict from."""
        return self._pose is not None

    @property
    def velocity(self) -> np.ndarray | None:
        return None if self._pose is None else self._pose / self.interval_s

    @property
    def velocity_covariance(self) -> np.ndarray | None:
        return None if self._cov is None else self._cov / self.interval_s**2

    def observe(self, pose, cov, dt_s: float) -> None:
        """Set the velocity from a relative pose ``pose`` (float[3]) over ``dt_s`` seconds."""
        dt = float(dt_s)
        if not dt > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s!r}")
        self._pose = np.array(pose, dtype=np.float64).reshape(3)
        self._cov = _sym(cov)
        self.interval_s = dt

    def predict(self, dt_s: float, lead_s: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
        """Predicted relative pose over the next ``dt_s`` seconds, or None without a velocity.

        Args:
            dt_s: length of the predicted interval, s (> 0).
            lead_s: time from the end of the velocity's interval to the start of the predicted
                one, s (0 for consecutive sweeps; more after skipped or gated sweeps).
        Returns:
            (pose_pred float64[3] = v·dt, cov_pred float64[3, 3] = dt²·P_v + Q(dt, τ)) with
            τ = interval/2 + lead + dt/2 (see `MotionPriorConfig.process_noise`).
        """
        if self._pose is None:
            return None
        dt = float(dt_s)
        if not dt > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s!r}")
        tau = 0.5 * self.interval_s + max(float(lead_s), 0.0) + 0.5 * dt
        k = dt / self.interval_s
        pose = self._pose * k
        pose[2] = wrap_angle(pose[2])
        cov = k * k * self._cov + self.config.process_noise(dt, tau)
        return pose, _sym(cov)

    def prior_for(self, dt_s: float, lead_s: float = 0.0, odometry=None,
                  use_prediction: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
        """The prior for one interval: prediction ⊕ external odometry (either may be absent).

        ``odometry`` is an `ExternalOdometry` (taken over ``dt_s``) or a ready (pose, cov) pair.
        """
        pred = self.predict(dt_s, lead_s) if use_prediction else None
        if odometry is not None and not isinstance(odometry, tuple):
            odometry = ExternalOdometry.coerce(odometry).relative_pose(dt_s)
        if odometry is None:
            return pred
        if pred is None:
            return np.asarray(odometry[0], dtype=np.float64), _sym(odometry[1])
        f, cf, _ = fuse(odometry[0], odometry[1], pred[0], pred[1])
        return f, cf

    def update(self, measurement, meas_cov, dt_s: float, lead_s: float = 0.0, odometry=None,
               use_prediction: bool = True) -> PriorStep:
        """Gate and fuse one measurement with the prior, then update the velocity.

        Args:
            measurement: float[3] relative pose measured over the interval (x m, y m, yaw rad).
            meas_cov: float[3, 3] its covariance.
            dt_s: the interval's length, s.
            lead_s: see `predict`.
            odometry: `ExternalOdometry`, a dict of its fields, or a (pose, cov) pair over the
                interval; None for none.
            use_prediction: False leaves the constant-velocity prediction out (odometry only).
        Returns:
            `PriorStep` (see the module docstring for the steps and flags).
        """
        cfg = self.config
        m = _check("measurement", measurement, (3,)).copy()
        cm = _sym(_check("measurement covariance", meas_cov, (3, 3)))
        prior = self.prior_for(dt_s, lead_s, odometry, use_prediction)
        if prior is None:  # first step of a stream: nothing to fuse
            self.observe(m, cm, dt_s)
            self.consecutive_gated = 0
            return PriorStep(m, cm)
        p, cp = prior
        d2 = mahalanobis_d2(innovation(m, p), cm + cp)
        if d2 > cfg.gate_d2:
            if self.consecutive_gated >= cfg.max_consecutive_gated:
                # the prior has overridden the measurements long enough: believe them again
                self.observe(m, cm, dt_s)
                self.consecutive_gated = 0
                return PriorStep(m, cm, frozenset({PRIOR_RESET}), d2, 0.0, (p, cp))
            self.consecutive_gated += 1
            k = cfg.report_prior_scale
            return PriorStep(p.copy(), k * cp if k != 1.0 else cp.copy(), frozenset({GATED, PRIOR_DOMINATED}),
                             d2, 1.0, (p, cp), cp.copy() if k != 1.0 else None)
        self.consecutive_gated = 0
        ip = inv_psd(cp)
        ip_used = taper_information(cm, ip) if cfg.taper else ip
        f, cf, info = fuse_information(m, cm, p, ip_used, d2_cov=cp)
        flags = frozenset({PRIOR_DOMINATED}) if info["prior_share"] > cfg.prior_dominated_share else frozenset()
        self.observe(f, cf, dt_s)
        if cfg.report_prior_scale == 1.0:
            return PriorStep(f, cf, flags, d2, info["prior_share"], (p, cp))
        reported = inv_psd(inv_psd(cm) + ip_used / cfg.report_prior_scale)
        return PriorStep(f, reported, flags, d2, info["prior_share"], (p, cp), cf)
