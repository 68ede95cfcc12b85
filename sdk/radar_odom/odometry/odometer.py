"""`RadarOdometer`: radar odometry over a stream of sweeps with one exported ONNX graph.

    odo = RadarOdometer("model.onnx")
    for scan in sweeps:
        est = odo.step(scan)          # None for the first sweep of a stream
    odo.trajectory.poses              # float64[N, 3, 3] absolute poses, first sweep = identity

An `Estimate` is the pose of the new sweep expressed in the previous sweep's frame (Oxford
ground-truth convention, see `radar_odom.se2`) with its 3×3 covariance over (x, y, yaw).

Faults, and what the odometer does about them (never a NaN, never a broken trajectory):

- A sweep whose timestamp (first azimuth) does not increase → `StreamError`.
- Time: the stamps only advise. A step spans whole periods of the sensor; the stamps give a count
  (`stream_time.StreamClock`), the match decides it (`radar_odom.odometry.match_stage`): a readable
  match that agrees with one period of motion per sweep means nothing was dropped, whatever the
  stamps say (a late stamp, a stall, a catch-up). The motion prior counts in periods, so a jittered
  clock moves no pose. A step the match takes to span dropped sweeps is flagged ``"gap"``.
- Gaps (dropped sweeps, a stalled recorder): where the stamps say sweeps were dropped and the plain
  match cannot read the step, it is matched centred on the prediction, then from several window
  centres, else it is the prediction (`radar_odom.odometry.match_stage`, docs/gaps.md); a crossing
  no single readable match confirmed is flagged ``"uncertain"`` with a covariance that covers the
  gap's prior. Beyond `NEW_SEGMENT_GAP_S` (10 s; a clock reset) no prediction places the search
  window, so the sweep starts a new segment: kept at the last pose with the window's covariance,
  flagged ``"new_segment"``, the stream restarted from it. With ``max_gap_s`` set, a longer gap
  is a hard stop instead: ``on_gap="raise"`` (default) raises `StreamError` (call `reset()` and go
  on); ``on_gap="reset"`` resets the stream itself, so that sweep starts a new trajectory at
  identity and `step` returns None.
- Sweep geometry. A Cartesian-input model runs on any sweep geometry (azimuth count, bin count,
  range resolution and offset may all differ from the radar it was trained on): the sweep is
  resampled onto the model's grid first. It needs only a sweep that reaches the disc it
  correlates (`GridProfile.support_radius_m`); a shorter one (``max_range_m`` below that radius)
  → `ModelMismatchError` giving both ranges. A polar-input model is built for one geometry: a
  sweep whose geometry differs from the one in the model's metadata → `ModelMismatchError`
  naming both.
- A *degenerate* sweep, judged on the part the model sees (range bins from the near-range cut
  ``near_range_m`` to the correlated disc ``support_radius_m``; `sweep_problem`) — mostly
  invalid (fewer than ``min_valid_fraction`` of its azimuth rows valid), covering less than
  ``min_coverage`` of the turn, saturated (most of it at full scale), blank (almost no power)
  or noise only (no spatial structure) — a sweep that could not be read at all (`skip`), or a
  graph output that is not finite: the estimate is the constant-velocity prior (the previous relative
  pose scaled by the time step; zero if there is none) with the covariance of a uniform
  distribution over the whole search window (``a²/3`` per axis for a window ``±a``), and its
  ``flags`` hold ``"degenerate"`` and the reason. Such a sweep never becomes the reference:
  the next sweep is matched against the last good one and its estimate, flagged ``"bridged"``,
  is re-expressed relative to the degenerate sweep's prior pose, so the absolute trajectory
  follows the good matches. A bridged covariance is the match covariance plus the window
  covariance (first order: the prior pose it is relative to is that uncertain).

Motion prior (`radar_odom.odometry.motion_prior`; on by default, ``motion_prior=False`` turns it off,
a `MotionPriorConfig` tunes it). From the second estimate of a stream on, each match is fused in
information form with a constant-velocity prediction from the previous estimates (and with
external odometry, when `step` is given some): a direction the match leaves unconstrained is
carried by the prediction, a well-constrained one keeps the match. A match that is implausible
given the prediction (innovation d² above a χ² gate) is not averaged in: the estimate is the
prediction, flagged ``"gated"``; after two gated steps in a row the next failing match is taken
as it is (``"prior_reset"``), so a wrong prediction cannot lock the odometer. An estimate whose
motion comes mostly from the prior is flagged ``"prior_dominated"``. ``Estimate.pose`` and
``.covariance`` are the fused values (the covariance as `radar_odom.odometry.motion_prior` reports it:
with the prior's information discounted, step 8 there); ``Estimate.measurement`` and ``.measurement_covariance``
the match as it came from the graph (re-expressed like the pose when bridged). Degenerate
estimates use the same prediction and never update the velocity. A bridged match is fused over
its whole interval (from the last good sweep), before it is re-expressed. With
``motion_prior=False`` and no external odometry the odometer behaves as it did before the prior
existed (the velocity is still tracked, for degenerate sweeps and gaps).

Motion compensation (``deskew=True``; Cartesian models): each sweep drawn as seen from the sensor at
its first azimuth's instant, both sweeps of a match with one twist (`radar_odom.odometry.deskew_stage`).

Yaw centring (``centre_yaw=True``; Cartesian models; off by default): each sweep drawn turned by
the predicted yaw, so the pull of the pixel grids goes toward the prediction rather than toward
"no rotation" (`radar_odom.odometry.centring`; measured in docs/yaw-precision.md: simulated bends
read more fully, the real drive worse, hence off).
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, InputTypeError, ModelMismatchError
from ..onnx_model import OnnxModel
from ..scan import RadarScan
from ..se2 import invert, se2, to_xyyaw
from . import stream_time
from .arguments import stream_timestamp
from .config import OdometerConfig, config_from
from .deskew_stage import DESKEW_STEPS, DeskewStage  # noqa: F401  (DESKEW_STEPS re-exported: its home was here)
from .estimate import BRIDGED, DEGENERATE, Estimate, PreparedSweep, Trajectory, window_covariance  # noqa: F401
from .gaps import GAP, NEW_SEGMENT, NEW_SEGMENT_GAP_S
from .graph_step import GraphStep
from .match_stage import Match, MatchStage
from .motion_prior import GATED, ExternalOdometry, MotionPrior, MotionPriorConfig
from .motion_prior import compose as compose_relative
from .motion_prior import fuse as fuse_estimates
from .sweep_checks import (  # noqa: F401  (re-exported: their home was here)
    MIN_COVERAGE,
    NOISE_STRUCTURE,
    azimuth_coverage,
    check_sweep_geometry,
    model_region_m,
    sweep_problem,
)
from .sweep_input import SweepMotion, graph_input

# De-skew and yaw centring: measured options, off by default (`OdometerConfig.deskew`)
DESKEW_DEFAULT = False
CENTRE_YAW_DEFAULT = False
# what step()/prepare() say to a caller passing an array: how to make the sweep they take
SCAN_HINT = ("wrap the sweep first: RadarScan.from_arrays(timestamps_us, azimuths_rad, power, "
             "range_resolution_m=...) for arrays, radar_odom.load_scan(path) for a file")
RECENT_PERIODS = 4  # the last second of steps (4 Hz): the yaw rates a gap crossing must be drivable from


def _is_loaded_model(model) -> bool:
    """True for a model object with `OnnxModel`'s interface (``info``, ``path``, ``run``) rather than a path."""
    return all(hasattr(model, a) for a in ("info", "path", "run")) and callable(model.run)


@dataclass
class Reference:
    """The sweep new ones are matched against: the graph's state of it (``feed``), its place in the
    trajectory (``index``), the sweep as recorded (``scan``: a gap crossing redraws it) and the turn (rad)
    it was drawn with (`radar_odom.odometry.centring`)."""

    feed: np.ndarray | None = None
    index: int = -1
    scan: RadarScan | None = None
    turn: float = 0.0


class StreamState:
    """One stream's state: the trajectory (poses, stamps, and each sweep's place on the sensor's period
    count, ``ticks``), the reference, where the velocity's interval ends, external odometry since the
    reference, the last second's yaw rates, and the stream's range bins and azimuth count."""

    def __init__(self):
        self.poses: list[np.ndarray] = []
        self.stamps: list[int] = []
        self.ticks: list[int] = []
        self.ref = Reference()
        self.velocity_end_tick: int | None = None
        self.odometry_since_ref: tuple | None = None  # (pose, cov) reference → latest sweep; None if unknown
        self.yaw_rates: deque = deque(maxlen=RECENT_PERIODS)
        self.range_scale: tuple | None = None
        self.azimuths: int | None = None

    def forget_motion(self) -> None:
        self.velocity_end_tick = None
        self.odometry_since_ref = None
        self.yaw_rates.clear()

    def append(self, absolute: np.ndarray, ts: int, periods: int) -> None:
        self.poses.append(absolute)
        self.stamps.append(int(ts))
        self.ticks.append(self.ticks[-1] + int(periods) if self.ticks else 0)


class RadarOdometer:
    """Odometry with an exported radar-odom ONNX model, configured from its metadata.

    Args:
        model: path of the ``.onnx`` file (e.g. ``radar_odom.pretrained("cart-0.4")``), any form but the
            sequence's (a sweep-form file draws the Cartesian image in its graph: no de-skew, gap crossing or
            yaw centring, which draw it moved), or a loaded model (`OnnxModel`, `radar_odom.runtimes.OpenVinoModel`).
        threads: onnxruntime intra-op threads; default: the number of physical cores.
        providers: onnxruntime execution providers; default CPU.
        config: an `OdometerConfig` (None: the default), or ``"plain"`` (`OdometerConfig.plain`).
        motion_prior: True, False (no fusion or gate) or a `MotionPriorConfig`: the config's ``prior`` replaced.
        **options: the config's fields by their earlier keyword names, applied on top of ``config``:
            ``max_gap_s``, ``on_gap``, ``sweep_period_s`` (`TimeConfig`), ``min_valid_fraction``,
            ``min_coverage`` (`SweepCheckConfig`), ``deskew``, ``centre_yaw`` (`DeskewConfig`),
            ``deskew_gaps`` (``GapConfig.deskew``).

    Raises `ConfigError` (a ValueError) for an option it cannot use; `InvalidModelError` for a corrupt
    model file or metadata (see `radar_odom.onnx_model`); a warning-free `ConfigError` where a loaded model
    is given with ``threads``/``providers`` (they configure a session it already has).

    Threads: `step`, `skip`, `reset` and `trajectory` are serialised by a lock held for the
    whole call, so one odometer stepped from several threads never interleaves the inside of
    two steps. A stream should be fed by one thread; use one odometer per stream for parallelism.
    """

    def __init__(self, model, threads: int | None = None, providers=None, *, config: OdometerConfig | str | None = None,
                 motion_prior: bool | MotionPriorConfig | None = None, **options):
        self.config = config_from(config, motion_prior=motion_prior, **options)
        loaded = isinstance(model, OnnxModel) or _is_loaded_model(model)
        if loaded and (threads is not None or providers is not None):
            raise ConfigError("threads= and providers= configure the session RadarOdometer makes from a path; this "
                              "model is loaded already: give them to its constructor (OnnxModel(path, threads, "
                              "providers), OpenVinoModel(path, ...)) instead")
        self._model = model if loaded else OnnxModel(model, threads, providers)
        self.info = self._model.info
        self._graph = GraphStep(self._model)
        if self.info.form == "sequence":
            raise ModelMismatchError(
                f"{self._model.path.name} is a sequence-form model (offline batches of consecutive sweeps); "
                "use radar_odom.match_sequence with it, or a stream-form model (radar_odom.pretrained) here"
            )
        self.profile = self.info.profile
        self._prior_cov = window_covariance(self.profile)
        self._lock = threading.RLock()
        self.sweep_region_m = model_region_m(self.info)
        # a polar model's graph reads the sweep as recorded, a sweep-form graph draws it as recorded: neither
        # de-skew nor a moved frame (nor the gap crossing and yaw centring, which draw the sweep moved)
        self._movable = self.profile.input_kind != "polar" and self.info.form != "sweep"
        cfg = self.config
        if not self._movable and (cfg.deskew.enabled or cfg.deskew.centre_yaw):
            raise ConfigError(f"{self._model.path.name} is a {self.info.form}-form {self.profile.input_kind} model: "
                              "its graph reads the sweep as recorded, so it cannot be de-skewed or drawn turned; "
                              "leave deskew and centre_yaw off, or use a Cartesian stream model "
                              "(radar_odom.pretrained)")
        self._prior = MotionPrior(cfg.prior)  # the velocity is tracked with fusion off too (degenerate sweeps, gaps)
        self._period_s = cfg.time.prior_period_s
        self._clock = stream_time.StreamClock(cfg.time.sweep_period_s)
        self._deskew_stage = DeskewStage(cfg.deskew.enabled, self.profile, self.info.mount_yaw_rad,
                                         self._redraw_reference)
        self._match_stage = MatchStage(
            self.profile, self.info.mount_yaw_rad, self._movable, cfg.deskew.centre_yaw, cfg, self._prior,
            lambda x, keep_reference=False: self._graph.match(x, self._state.ref.feed, keep_reference),
            self._graph.first, lambda scan, motion=None: self._sweep_input(scan, motion),
            run_against=lambda x, reference: self._graph.match(x, reference, True))
        self.reset()

    # --- configuration, read back -----------------------------------------------------------
    @property
    def path(self):
        return self._model.path

    @property
    def max_gap_s(self) -> float | None:
        return self.config.time.max_gap_s

    @property
    def on_gap(self) -> str:
        return self.config.time.on_gap

    @property
    def min_valid_fraction(self) -> float:
        return self.config.checks.min_valid_fraction

    @property
    def min_coverage(self) -> float:
        return self.config.checks.min_coverage

    @property
    def motion_prior(self) -> MotionPriorConfig | None:
        """The motion prior's configuration, or None when it is off."""
        return self.config.prior

    @property
    def deskew(self) -> bool:
        return self._deskew_stage.enabled

    @property
    def centre_yaw(self) -> bool:
        return self._match_stage.centre_yaw

    @property
    def reference_redraws(self) -> int:
        """Graph calls spent redrawing a reference for de-skew (this stream; `DeskewStage.redraws`)."""
        return self._deskew_stage.redraws

    @property
    def sweep_period_s(self) -> float | None:
        """The period (s) the stream's stamps are read in (`stream_time.StreamClock`), or None while unknown."""
        with self._lock:
            return self._clock.period_s

    def reset(self) -> None:
        """Forget the stream: the next sweep starts a new trajectory at identity."""
        with self._lock:
            self._state = StreamState()
            self._deskew_stage.reset()
            self._forget_motion()

    def _forget_motion(self) -> None:
        """Forget how the stream moved (a new stream, or a new segment after a stamp jump)."""
        self._prior.reset()
        self._state.forget_motion()
        self._clock.reset()
        self._deskew_stage.forget_motion()

    @property
    def trajectory(self) -> Trajectory:
        with self._lock:
            st = self._state
            if not st.poses:
                return Trajectory(np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64))
            return Trajectory(np.stack(st.poses), np.asarray(st.stamps, dtype=np.int64))

    def sweep_problem(self, scan: RadarScan) -> str | None:
        """Why ``scan`` would be degenerate for this model (`sweep_problem` on the model's region)."""
        lo, hi = self.sweep_region_m
        return sweep_problem(scan, self.min_valid_fraction, min_range_m=lo, max_range_m=hi,
                             min_coverage=self.min_coverage)

    # --- the step -------------------------------------------------------------------------
    def prepare(self, scan: RadarScan) -> PreparedSweep:
        """The stream-independent part of `step` for ``scan``, done now (any thread may call it).

        ``odo.step(odo.prepare(scan))`` gives exactly what ``odo.step(scan)`` gives; preparing the
        next sweeps on a worker thread while `step` runs the graph overlaps the two (what
        `radar_odom.odometry.pipeline.iter_estimates` does). Reads only the odometer's configuration.
        """
        if not isinstance(scan, RadarScan):
            raise InputTypeError(f"prepare() takes a RadarScan, got {type(scan).__name__}; {SCAN_HINT}")
        try:
            self._check_geometry(scan)
        except ModelMismatchError:  # raised by step(), in the stream's order
            return PreparedSweep(scan, None, None, ready=False, owner=self)
        problem = self.sweep_problem(scan)
        x = self._sweep_input(scan) if problem is None else None
        return PreparedSweep(scan, problem, x, ready=True, owner=self)

    def iter_estimates(self, source, *, prefetch: int = 2, on_error: str = "skip"):
        """`radar_odom.odometry.pipeline.iter_estimates` with this odometer (see there)."""
        from .pipeline import iter_estimates

        return iter_estimates(source, self, prefetch=prefetch, on_error=on_error)

    def step(self, scan: RadarScan | PreparedSweep,
             odometry: ExternalOdometry | dict | None = None) -> Estimate | None:
        """Add one sweep; return its pose relative to the previous sweep (None for the first).

        Args:
            scan: the new sweep, or the `PreparedSweep` that `prepare` made of it.
            odometry: optional `ExternalOdometry` (or a dict of its fields): wheel speed and/or
                yaw rate over the interval since the previous sweep, fused with the match in
                information form like the constant-velocity prediction (also with the prior
                off). Ignored for the first sweep of a stream.
        """
        prepared = None
        if isinstance(scan, PreparedSweep):
            prepared = scan if scan.ready and scan.owner is self else None
            scan = scan.scan
        if not isinstance(scan, RadarScan):
            raise InputTypeError(f"step() takes a RadarScan, got {type(scan).__name__}; {SCAN_HINT}")
        odometry = ExternalOdometry.coerce(odometry)
        with self._lock:
            return self._step(scan, odometry, prepared)

    def skip(self, timestamp_us: int, reason: str = "unreadable", source: str = "sweep") -> Estimate | None:
        """Record a sweep that exists but cannot be used (e.g. its file is corrupt).

        The sweep gets a pose like a degenerate one: the constant-velocity prediction with the
        search window's covariance, flagged ``{"degenerate", reason}``; it never becomes the
        reference, so the next good sweep is matched across it (``"bridged"``). The trajectory
        keeps one pose per sweep. Time checks are those of `step` (`StreamError`); the first
        sweep of a stream is recorded at identity (returns None).
        """
        ts = stream_timestamp(timestamp_us, source)
        with self._lock:
            if self._check_time(ts, source):
                self._state.append(np.eye(3), ts, 0)
                return None
            dt_s = (ts - self._state.stamps[-1]) * 1e-6
            periods = self._clock.periods(dt_s)
            return self._degenerate(str(reason), ts, periods, None, self._gap_flags(periods))

    def _check_time(self, ts: int, source: str) -> bool:
        """`StreamError` unless ``ts`` may follow the stream (resets it on a gap with
        ``on_gap="reset"``); True when ``ts`` starts a new stream."""
        st = self._state
        if st.stamps:
            dt_s = stream_time.interval_s(ts, st.stamps[-1], source)
            if self.max_gap_s is not None and dt_s > self.max_gap_s:
                if self.on_gap != "reset":
                    raise stream_time.beyond_max_gap(source, dt_s, self.max_gap_s)
                self.reset()
        return not self._state.stamps

    def _step(self, scan: RadarScan, odometry, prepared: PreparedSweep | None = None) -> Estimate | None:
        """One sweep through the stages (`radar_odom.odometry` names each stage's home)."""
        # time: in order after the stream, the same range bins; a new stream or a new segment
        self._check_geometry(scan)
        ts = scan.timestamp_us
        first = self._check_time(ts, scan.source)
        st = self._state
        st.range_scale = stream_time.range_bins(scan, None if first else st.range_scale)
        # sweep checks: can the model read it at all (the stream's azimuth rows first: the others judge it alone)
        st.azimuths, problem = stream_time.azimuth_count(scan, None if first else st.azimuths)
        problem = problem or (self.sweep_problem(scan) if prepared is None else prepared.problem)
        if first:
            return self._start_stream(scan, prepared, problem, ts)
        dt_s = (ts - st.stamps[-1]) * 1e-6
        if self.max_gap_s is None and dt_s > NEW_SEGMENT_GAP_S:
            return self._new_segment(scan, prepared, problem, ts)
        stamp_periods = self._clock.periods(dt_s)  # the stamps' count: advice, the match decides
        odo_rel = odometry.relative_pose(dt_s) if odometry is not None else None
        if problem is not None:
            self._clock.observe(dt_s, stamp_periods)
            return self._degenerate(problem, ts, stamp_periods, odo_rel, self._gap_flags(stamp_periods))
        if st.ref.feed is None:
            self._clock.observe(dt_s, stamp_periods)
            return self._first_reference(scan, prepared, ts, stamp_periods, odo_rel)
        # graph input: drawn with the reference's twist (de-skew stage), else as prepared
        twist = self._deskew_stage.pair_twist(scan)
        x = self._input(scan, prepared, twist)
        # predict and match: the match decides the periods; across a gap, from the prediction; a de-skewed
        # stream's first match drawn again with the velocity it measured
        since_ref = st.ticks[-1] - st.ticks[st.ref.index] + stamp_periods
        out = self._match(scan, x, twist, since_ref)
        out, twist = self._deskew_stage.first_match(
            scan, out.periods * self._period_s if out is not None else 0.0, out, twist,
            lambda drawn: self._match(scan, self._input(scan, None, drawn), drawn, since_ref))
        if out is None:
            self._clock.observe(dt_s, stamp_periods)
            return self._degenerate("nonfinite", ts, stamp_periods, odo_rel, self._gap_flags(stamp_periods))
        # the periods of this interval alone: those the match spans less those already behind the last sweep
        periods = max(1, out.periods - (st.ticks[-1] - st.ticks[st.ref.index]))
        self._clock.observe(dt_s, periods)
        est = self._accept(out, ts, periods, odo_rel)
        self._deskew_stage.keep_reference(scan, twist)
        st.ref.scan = scan
        return est

    def _start_stream(self, scan: RadarScan, prepared, problem, ts: int) -> None:
        """A stream's first sweep, recorded at identity. A stream must start from a sweep that can be
        matched: a degenerate first sweep is recorded but never becomes the reference."""
        self._clock.adopt_rotation(scan)
        self._state.append(np.eye(3), ts, 0)
        if problem is None:
            self._make_reference(scan, prepared, None, 0)  # no velocity yet
        return None

    def _first_reference(self, scan: RadarScan, prepared, ts: int, periods: int, odo_rel) -> Estimate:
        """Every earlier sweep of the stream was degenerate: nothing to match against yet, so this
        one gets the prior's pose (flagged ``no_reference``) and becomes the reference."""
        twist = self._deskew_stage.stream_twist(scan)
        est = self._degenerate("no_reference", ts, periods, odo_rel, self._gap_flags(periods))
        self._make_reference(scan, prepared, twist, len(self._state.poses) - 1)
        return est

    def _make_reference(self, scan: RadarScan, prepared, twist, index: int) -> None:
        """Make the sweep at trajectory ``index`` the reference, drawn with ``twist`` in its own frame."""
        self._state.ref = Reference(self._graph.first(self._input(scan, prepared, twist)), index, scan, 0.0)
        self._state.odometry_since_ref = (np.zeros(3), np.zeros((3, 3)))
        self._deskew_stage.keep_reference(scan, twist)

    # --- pieces ---------------------------------------------------------------------------
    def _new_segment(self, scan: RadarScan, prepared, problem, ts: int) -> Estimate:
        """After a stamp jump beyond `NEW_SEGMENT_GAP_S`: the motion over it is unknown, so the sweep
        is placed at the last pose with the search window's covariance, flagged ``new_segment``,
        and the stream starts afresh from it (velocity, period and de-skew history forgotten)."""
        self._forget_motion()
        st = self._state
        st.ref = Reference()
        st.append(st.poses[-1].copy(), ts, 1)
        if problem is None:
            self._make_reference(scan, prepared, None, len(st.poses) - 1)
        flags = {NEW_SEGMENT} if problem is None else {NEW_SEGMENT, DEGENERATE, problem}
        return Estimate(np.zeros(3), self._prior_cov.copy(), ts, frozenset(flags))

    def _check_geometry(self, scan: RadarScan) -> None:
        check_sweep_geometry(scan, self.info, self.path.name)

    def _sweep_input(self, scan: RadarScan, motion: SweepMotion | None = None) -> np.ndarray:
        return graph_input(scan, self.info, motion)

    def _redraw_reference(self, ref_scan: RadarScan, twist) -> bool:
        """The de-skew stage's graph call: the reference sweep drawn again with ``twist`` (and its turn)
        becomes the reference; False (the reference kept) where the graph's output is not finite."""
        feed = self._match_stage.draw_reference(ref_scan, twist, self._state.ref.turn)
        if feed is None:
            return False
        self._state.ref.feed = feed
        return True

    @staticmethod
    def _gap_flags(periods: int) -> set:
        return {GAP} if periods > 1 else set()

    def _input(self, scan: RadarScan, prepared: PreparedSweep | None, twist) -> np.ndarray:
        """The graph input of the sweep as the stream takes it: de-skewed when that is on (the
        prepared image is drawn without the velocity, which only the stream knows)."""
        if twist is not None:
            return self._sweep_input(scan, SweepMotion(twist=twist))
        return self._sweep_input(scan) if prepared is None else prepared.input

    def _match(self, scan: RadarScan, x: np.ndarray, twist, stamp_periods: int) -> Match | None:
        """The predict and match stages (`MatchStage.match`) of the new sweep against the reference."""
        st = self._state
        sweeps = len(st.poses) - st.ref.index
        return self._match_stage.match(scan, x, twist, sweeps, stamp_periods, self._lead_s(st.ref.index),
                                       st.ref.turn, ref_scan=st.ref.scan, recent_yaw_rates=tuple(st.yaw_rates))

    def _lead_s(self, index: int) -> float:
        """Seconds (in periods) from the end of the velocity's interval to the sweep at ``index``."""
        end = self._state.velocity_end_tick
        return 0.0 if end is None else max(0, self._state.ticks[index] - end) * self._period_s

    def _accept(self, m: Match, ts: int, periods: int, odo_rel=None) -> Estimate:
        """A match of the new sweep against the reference, fused with the prior, chained on."""
        st = self._state
        ref_pose, ref_tick = st.poses[st.ref.index], st.ticks[st.ref.index]
        bridged = st.ref.index != len(st.poses) - 1
        interval_s = (st.ticks[-1] + periods - ref_tick) * self._period_s
        odo_interval = None
        if odo_rel is not None and st.odometry_since_ref is not None:
            odo_interval = compose_relative(*st.odometry_since_ref, *odo_rel)
        flags = set(m.flags)
        use_prediction = self.config.prior is not None
        if use_prediction or odo_interval is not None:
            res = self._prior.update(m.pose, m.cov, interval_s, self._lead_s(st.ref.index),
                                     odometry=odo_interval, use_prediction=use_prediction)
            fused, fused_cov = res.pose, res.covariance
            flags |= res.flags
            if GATED not in res.flags:
                st.velocity_end_tick = st.ticks[-1] + periods
        else:
            fused, fused_cov = m.pose, m.cov
        absolute = ref_pose @ se2(*fused)
        if not bridged:
            rel, meas, meas_cov = fused, m.pose, m.cov
        else:  # bridged across degenerate sweeps: re-express against the previous (prior) pose
            to_prev = invert(st.poses[-1])
            rel = to_xyyaw(to_prev @ absolute)
            meas = to_xyyaw(to_prev @ ref_pose @ se2(*m.pose))
            fused_cov = fused_cov + self._prior_cov
            meas_cov = m.cov + self._prior_cov
            flags.add(BRIDGED)
        if m.cover is not None:  # an uncertain crossing: its covariance covers the gap's prior
            fused_cov = fused_cov + m.cover
            meas_cov = meas_cov + m.cover
        if not (use_prediction or odo_interval is not None):
            # no fusion: the velocity follows the reported steps (degenerate sweeps and gaps predict from it)
            self._prior.observe(rel, fused_cov, periods * self._period_s)
            st.velocity_end_tick = st.ticks[-1] + periods
        if GATED not in flags:
            self._deskew_stage.observe(rel, periods * self._period_s)
            st.yaw_rates.append(float(fused[2]) / interval_s)
        st.append(absolute, ts, periods)
        st.ref = Reference(m.new_ref, len(st.poses) - 1, None, float(m.turn))
        st.odometry_since_ref = (np.zeros(3), np.zeros((3, 3)))
        return Estimate(np.asarray(rel, dtype=np.float64), fused_cov, ts, frozenset(flags),
                        np.array(meas, dtype=np.float64), np.array(meas_cov, dtype=np.float64))

    def _degenerate(self, reason: str, ts: int, periods: int, odo_rel=None, flags=None) -> Estimate:
        """Constant-velocity prediction with the search window's covariance; the reference stays.

        With external odometry, that is fused in (information form). The velocity is not updated.
        """
        st = self._state
        pred = self._prior.predict(periods * self._period_s, self._lead_s(len(st.poses) - 1))
        rel = pred[0] if pred is not None else np.zeros(3)
        cov = self._prior_cov.copy()
        if odo_rel is not None:
            rel, cov, _ = fuse_estimates(odo_rel[0], odo_rel[1], rel, cov)
        if st.odometry_since_ref is not None:
            st.odometry_since_ref = (compose_relative(*st.odometry_since_ref, *odo_rel)
                                     if odo_rel is not None else None)
        st.append(st.poses[-1] @ se2(*rel), ts, periods)
        return Estimate(np.array(rel, dtype=np.float64), cov, ts, frozenset({DEGENERATE, reason, *(flags or ())}))
