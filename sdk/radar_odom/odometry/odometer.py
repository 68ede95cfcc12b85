"""`RadarOdometer`: radar odometry over a stream of sweeps with one exported ONNX graph.

    odo = RadarOdometer("model.onnx")                 # or config=OdometerConfig.plain(), motion_prior=False, …
    for scan in sweeps:
        est = odo.step(scan)          # None for the first sweep of a stream
    odo.trajectory.poses              # float64[N, 3, 3] absolute poses, first sweep = identity

An `Estimate` is the pose of the new sweep expressed in the previous sweep's frame (Oxford ground-truth
convention, `radar_odom.se2`) with its 3×3 covariance over (x, y, yaw). A step runs the stages of
`RadarOdometer._stages` in order, each a method from (stream state, sweep) to the estimate or on to the next
(`radar_odom.odometry` names each stage's home):

- **time** (`stream_time`): the sweep's stamp must increase (`StreamError`); beyond ``max_gap_s`` a hard stop
  (``on_gap="raise"``) or a new stream (``"reset"``); beyond `NEW_SEGMENT_GAP_S` (10 s: a clock reset, where
  no prediction can place the window) a new segment, kept at the last pose with the window's covariance,
  flagged ``"new_segment"``. The stamps give a count of the sensor's periods (`stream_time.StreamClock`):
  advice only, the match decides.
- **checks** (`sweep_checks`): a sweep the model cannot read — geometry short of the correlated disc or
  another polar geometry (`ModelMismatchError`), another range-bin scale (`StreamError`), mostly invalid,
  partial, saturated, blank, noise only, another azimuth count — is *degenerate*: the constant-velocity
  prediction with the search window's covariance, flagged ``{"degenerate", reason}``; it never becomes the
  reference, and the next sweep is matched across it (``"bridged"``, re-expressed against it).
- **match** (`match_stage`, `deskew_stage`): the graph against the reference. A readable match that agrees
  with one period of motion a sweep means nothing was dropped, whatever the stamps say; where the stamps say
  sweeps were dropped and the match cannot read the step, the gap is crossed (``"gap"``; ``"uncertain"``
  with a covariance that covers the gap's prior where no two window placements confirm it). A graph output
  that is not finite makes the sweep degenerate (``"nonfinite"``).
- **fuse** (`motion_prior`): the match with the constant-velocity prediction over its periods and any
  external odometry, in information form; a match beyond the χ² gate is replaced by the prediction
  (``"gated"``; after two, the next is taken: ``"prior_reset"``). ``Estimate.measurement`` keeps the match.

Every setting is one `OdometerConfig` (`radar_odom.odometry.config`); the plain mode is
``OdometerConfig.plain()``.
"""
from __future__ import annotations

import threading
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
from .stream_state import Reference, StreamState
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
NEXT = object()  # a stage's verdict: the step goes on to the next stage


@dataclass
class Sweep:
    """One sweep on its way through the stages: what came in, and what each stage found."""

    scan: RadarScan
    prepared: PreparedSweep | None
    odometry: ExternalOdometry | None
    ts: int = 0
    dt_s: float = 0.0
    stamp_periods: int = 1
    odo_rel: tuple | None = None  # external odometry over the interval (pose, cov)
    match: Match | None = None  # the match stage's
    twist: tuple | None = None  # the de-skew twist the new sweep was drawn with


def _is_loaded_model(model) -> bool:
    """True for a model object with `OnnxModel`'s interface (``info``, ``path``, ``run``) rather than a path."""
    return all(hasattr(model, a) for a in ("info", "path", "run")) and callable(model.run)


class RadarOdometer:
    """Odometry with an exported radar-odom ONNX model, configured from its metadata.

    Args:
        model: path of the ``.onnx`` file (e.g. ``radar_odom.pretrained("cart-0.4")``), any form but the
            sequence's, or a loaded model (`OnnxModel`, `radar_odom.runtimes.OpenVinoModel`).
        threads, providers: onnxruntime intra-op threads (default: the physical cores) and execution providers
            (default CPU) of the session made from a path; refused (`ConfigError`) with a loaded model.
        config: an `OdometerConfig` (None: the default), or ``"plain"`` (`OdometerConfig.plain`).
        motion_prior: True, False (no fusion or gate) or a `MotionPriorConfig`: the config's ``prior`` replaced.
        **options: the config's fields by their keyword names, applied on top of ``config``: ``max_gap_s``,
            ``on_gap``, ``sweep_period_s``, ``min_valid_fraction``, ``min_coverage``, ``deskew``, ``centre_yaw``
            (`radar_odom.odometry.config.LEGACY_KEYWORDS`).

    Raises `ConfigError` (a ValueError) for an option it cannot use (de-skew or yaw centring with a model that
    draws its sweeps itself included); `InvalidModelError` for a corrupt model file or metadata;
    `ModelMismatchError` for a sequence-form file (`radar_odom.match_sequence` takes it).

    Threads: `step`, `skip`, `reset` and `trajectory` are serialised by a lock held for the whole call, so one
    odometer fed from several threads never interleaves the inside of two steps; use one odometer per stream.
    """

    def __init__(self, model, threads: int | None = None, providers=None, *, config: OdometerConfig | str | None = None,
                 motion_prior: bool | MotionPriorConfig | None = None, **options):
        self.config = cfg = config_from(config, motion_prior=motion_prior, **options)
        loaded = isinstance(model, OnnxModel) or _is_loaded_model(model)
        if loaded and (threads is not None or providers is not None):
            raise ConfigError("threads= and providers= configure the session RadarOdometer makes from a path; this "
                              "model is loaded already: give them to its constructor (OnnxModel(path, threads, "
                              "providers), OpenVinoModel(path, ...)) instead")
        self._model = model if loaded else OnnxModel(model, threads, providers)
        self.info, self.profile = self._model.info, self._model.info.profile
        if self.info.form == "sequence":
            raise ModelMismatchError(
                f"{self._model.path.name} is a sequence-form model (offline batches of consecutive sweeps); "
                "use radar_odom.match_sequence with it, or a stream-form model (radar_odom.pretrained) here")
        self._graph = GraphStep(self._model)
        self._prior = MotionPrior(cfg.prior)  # the velocity is tracked with fusion off too (degenerate sweeps, gaps)
        self._matcher = MatchStage(self._graph, self.info, cfg, self._prior)
        if not self._matcher.movable and (cfg.deskew.enabled or cfg.deskew.centre_yaw):
            raise ConfigError(f"{self._model.path.name} is a {self.info.form}-form {self.profile.input_kind} model: "
                              "its graph reads the sweep as recorded, so it cannot be de-skewed or drawn turned; "
                              "leave deskew and centre_yaw off, or use a Cartesian stream model "
                              "(radar_odom.pretrained)")
        self._deskew = DeskewStage(cfg.deskew.enabled, self.profile, self.info.mount_yaw_rad, self._matcher)
        self._clock = stream_time.StreamClock(cfg.time.sweep_period_s)
        self._period_s = cfg.time.prior_period_s
        self._window_cov = window_covariance(self.profile)
        self.sweep_region_m = model_region_m(self.info)
        self._stages = (self._time_stage, self._check_stage, self._match_stage, self._fuse_stage)
        self._lock = threading.RLock()
        self.reset()

    # --- the configuration, read back ----------------------------------------------------------------------
    path = property(lambda self: self._model.path)
    max_gap_s = property(lambda self: self.config.time.max_gap_s)
    on_gap = property(lambda self: self.config.time.on_gap)
    min_valid_fraction = property(lambda self: self.config.checks.min_valid_fraction)
    min_coverage = property(lambda self: self.config.checks.min_coverage)
    motion_prior = property(lambda self: self.config.prior, doc="The prior's configuration, or None when it is off.")
    deskew = property(lambda self: self._deskew.enabled)
    centre_yaw = property(lambda self: self._matcher.centre_yaw)
    reference_redraws = property(lambda self: self._deskew.redraws, doc="Graph calls spent redrawing a reference.")

    @property
    def sweep_period_s(self) -> float | None:
        """The period (s) the stream's stamps are read in (`stream_time.StreamClock`), or None while unknown."""
        with self._lock:
            return self._clock.period_s

    @property
    def trajectory(self) -> Trajectory:
        with self._lock:
            st = self._state
            if not st.poses:
                return Trajectory(np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64))
            return Trajectory(np.stack(st.poses), np.asarray(st.stamps, dtype=np.int64))

    def reset(self) -> None:
        """Forget the stream: the next sweep starts a new trajectory at identity."""
        with self._lock:
            self._state = StreamState()
            self._deskew.reset()
            self._forget_motion()

    def _forget_motion(self) -> None:
        """Forget how the stream moved (a new stream, or a new segment after a stamp jump)."""
        self._prior.reset()
        self._state.forget_motion()
        self._clock.reset()
        self._deskew.forget_motion()

    def sweep_problem(self, scan: RadarScan) -> str | None:
        """Why ``scan`` would be degenerate for this model (`sweep_problem` on the model's region)."""
        lo, hi = self.sweep_region_m
        return sweep_problem(scan, self.min_valid_fraction, min_range_m=lo, max_range_m=hi,
                             min_coverage=self.min_coverage)

    # --- the public step ---------------------------------------------------------------------------------
    def prepare(self, scan: RadarScan) -> PreparedSweep:
        """The stream-independent part of `step` for ``scan``, done now (any thread may call it):
        ``odo.step(odo.prepare(scan))`` gives exactly what ``odo.step(scan)`` gives
        (`radar_odom.odometry.pipeline.iter_estimates` prepares the next sweeps while the graph runs)."""
        if not isinstance(scan, RadarScan):
            raise InputTypeError(f"prepare() takes a RadarScan, got {type(scan).__name__}; {SCAN_HINT}")
        try:
            check_sweep_geometry(scan, self.info, self.path.name)
        except ModelMismatchError:  # raised by step(), in the stream's order
            return PreparedSweep(scan, None, None, ready=False, owner=self)
        problem = self.sweep_problem(scan)
        return PreparedSweep(scan, problem, graph_input(scan, self.info) if problem is None else None,
                             ready=True, owner=self)

    def iter_estimates(self, source, *, prefetch: int = 2, on_error: str = "skip"):
        """`radar_odom.odometry.pipeline.iter_estimates` with this odometer (see there)."""
        from .pipeline import iter_estimates

        return iter_estimates(source, self, prefetch=prefetch, on_error=on_error)

    def step(self, scan: RadarScan | PreparedSweep, odometry: ExternalOdometry | dict | None = None) -> Estimate | None:
        """Add one sweep (or the `PreparedSweep` `prepare` made of it); return its pose relative to the previous
        sweep (None for the first of a stream). ``odometry``: optional `ExternalOdometry` (or a dict of its
        fields) over the interval since the previous sweep, fused like the prediction (also with the prior off)."""
        prepared = None
        if isinstance(scan, PreparedSweep):
            prepared = scan if scan.ready and scan.owner is self else None
            scan = scan.scan
        if not isinstance(scan, RadarScan):
            raise InputTypeError(f"step() takes a RadarScan, got {type(scan).__name__}; {SCAN_HINT}")
        sweep = Sweep(scan, prepared, ExternalOdometry.coerce(odometry))
        with self._lock:
            for stage in self._stages:
                out = stage(self._state, sweep)
                if out is not NEXT:
                    return out
        raise AssertionError("the fuse stage ends every step")  # pragma: no cover

    def skip(self, timestamp_us: int, reason: str = "unreadable", source: str = "sweep") -> Estimate | None:
        """Record a sweep that exists but cannot be used (e.g. its file is corrupt): a pose like a degenerate
        sweep's (the prediction, the window's covariance, ``{"degenerate", reason}``), never the reference.
        Time checks as `step`'s; the first sweep of a stream is recorded at identity (returns None)."""
        ts = stream_timestamp(timestamp_us, source)
        with self._lock:
            if self._check_time(ts, source):
                self._state.append(np.eye(3), ts, 0)
                return None
            periods = self._clock.periods((ts - self._state.stamps[-1]) * 1e-6)
            return self._degenerate(self._state, str(reason), ts, periods)

    # --- the stages: (stream state, sweep) -> Estimate | None, or NEXT ------------------------------------
    def _time_stage(self, st: StreamState, sw: Sweep):
        """In order after the stream and the same range bins; a new stream, or a new segment after a jump."""
        scan = sw.scan
        check_sweep_geometry(scan, self.info, self.path.name)
        sw.ts = scan.timestamp_us
        first = self._check_time(sw.ts, scan.source)
        st = self._state  # a reset on a gap made a new one
        st.range_scale = stream_time.range_bins(scan, None if first else st.range_scale)
        if first:
            return NEXT
        sw.dt_s = (sw.ts - st.stamps[-1]) * 1e-6
        if self.max_gap_s is None and sw.dt_s > NEW_SEGMENT_GAP_S:
            return self._new_segment(st, sw)
        # the stamps' count: advice, the match decides; on a stream's first step nothing can, so they need a margin
        first_step = self.config.time.match_decides and not self._prior.ready
        sw.stamp_periods = self._clock.periods(sw.dt_s, stream_time.FIRST_STEP_MARGIN if first_step else 0.0)
        sw.odo_rel = sw.odometry.relative_pose(sw.dt_s) if sw.odometry is not None else None
        return NEXT

    def _check_stage(self, st: StreamState, sw: Sweep):
        """Can the model read the sweep at all (the stream's azimuth rows first: the others judge it alone)."""
        first = not st.stamps
        st.azimuths, problem = stream_time.azimuth_count(sw.scan, None if first else st.azimuths)
        problem = problem or (self.sweep_problem(sw.scan) if sw.prepared is None else sw.prepared.problem)
        if first:  # a stream's first sweep, at identity; a degenerate one is recorded but never the reference
            self._clock.adopt_rotation(sw.scan)
            st.append(np.eye(3), sw.ts, 0)
            if problem is None:
                self._make_reference(st, sw, None, 0)
            return None
        if problem is None and st.ref.feed is not None:
            return NEXT
        self._clock.observe(sw.dt_s, sw.stamp_periods)
        est = self._degenerate(st, problem or "no_reference", sw.ts, sw.stamp_periods, sw.odo_rel)
        if problem is None:  # every earlier sweep was degenerate: this one gets the prior's pose and leads on
            self._make_reference(st, sw, self._deskew.stream_twist(sw.scan), len(st.poses) - 1)
        return est

    def _match_stage(self, st: StreamState, sw: Sweep):
        """The graph against the reference (drawn with the reference's twist); a de-skewed stream's first
        match drawn again with the velocity it measured."""
        twist = self._deskew.pair_twist(sw.scan, st.ref)
        since_ref = st.periods_since(st.ref.index) + sw.stamp_periods
        sweeps = len(st.poses) - st.ref.index

        def match(drawn_twist, x):
            return self._matcher.match(sw.scan, x, drawn_twist, st.ref, sweeps, since_ref, self._lead_s(st.ref.index),
                                       tuple(st.yaw_rates))

        out = match(twist, self._input(sw, twist))
        out, twist = self._deskew.first_match(sw.scan, st.ref, out.periods * self._period_s if out else 0.0, out, twist,
                                              lambda drawn: match(drawn, self._input(sw, drawn)))
        if out is None:
            self._clock.observe(sw.dt_s, sw.stamp_periods)
            return self._degenerate(st, "nonfinite", sw.ts, sw.stamp_periods, sw.odo_rel)
        sw.match, sw.twist = out, twist
        return NEXT

    def _fuse_stage(self, st: StreamState, sw: Sweep) -> Estimate:
        """The match fused with the prediction over its periods (and external odometry), chained on; the new
        sweep becomes the reference."""
        m: Match = sw.match
        periods = max(1, m.periods - st.periods_since(st.ref.index))  # this interval's, behind the last sweep
        self._clock.observe(sw.dt_s, periods)
        ref_pose, ref_tick = st.poses[st.ref.index], st.ticks[st.ref.index]
        interval_s = (st.ticks[-1] + periods - ref_tick) * self._period_s
        odo_interval = None
        if sw.odo_rel is not None and st.odometry_since_ref is not None:
            odo_interval = compose_relative(*st.odometry_since_ref, *sw.odo_rel)
        flags, fuse = set(m.flags), self.config.prior is not None or odo_interval is not None
        if fuse:
            res = self._prior.update(m.pose, m.cov, interval_s, self._lead_s(st.ref.index), odometry=odo_interval,
                                     use_prediction=self.config.prior is not None)
            fused, fused_cov, flags = res.pose, res.covariance, flags | res.flags
            if GATED not in res.flags:
                st.velocity_end_tick = st.ticks[-1] + periods
        else:
            fused, fused_cov = m.pose, m.cov
        absolute = ref_pose @ se2(*fused)
        rel, meas, meas_cov = fused, m.pose, m.cov
        if st.ref.index != len(st.poses) - 1:  # bridged across degenerate sweeps: against the last (prior) pose
            to_prev = invert(st.poses[-1])
            rel, meas = to_xyyaw(to_prev @ absolute), to_xyyaw(to_prev @ ref_pose @ se2(*m.pose))
            fused_cov, meas_cov = fused_cov + self._window_cov, meas_cov + self._window_cov
            flags.add(BRIDGED)
        if m.cover is not None:  # an uncertain crossing: its covariance covers the gap's prior
            fused_cov, meas_cov = fused_cov + m.cover, meas_cov + m.cover
        if not fuse:  # the velocity follows the reported steps (degenerate sweeps and gaps predict from it)
            self._prior.observe(rel, fused_cov, periods * self._period_s)
            st.velocity_end_tick = st.ticks[-1] + periods
        if GATED not in flags:
            self._deskew.observe(rel, periods * self._period_s)
            st.yaw_rates.append(float(fused[2]) / interval_s)
        st.append(absolute, sw.ts, periods)
        st.ref = Reference(m.new_ref, len(st.poses) - 1, sw.scan, float(m.turn), sw.twist)
        st.odometry_since_ref = (np.zeros(3), np.zeros((3, 3)))
        return Estimate(np.asarray(rel, dtype=np.float64), fused_cov, sw.ts, frozenset(flags),
                        np.array(meas, dtype=np.float64), np.array(meas_cov, dtype=np.float64))

    # --- pieces ------------------------------------------------------------------------------------------
    def _check_time(self, ts: int, source: str) -> bool:
        """`StreamError` unless ``ts`` may follow the stream (resets it beyond ``max_gap_s`` with
        ``on_gap="reset"``); True when ``ts`` starts a new stream."""
        if self._state.stamps:
            dt_s = stream_time.interval_s(ts, self._state.stamps[-1], source)
            if self.max_gap_s is not None and dt_s > self.max_gap_s:
                if self.on_gap != "reset":
                    raise stream_time.beyond_max_gap(source, dt_s, self.max_gap_s)
                self.reset()
        return not self._state.stamps

    def _new_segment(self, st: StreamState, sw: Sweep) -> Estimate:
        """After a stamp jump beyond `NEW_SEGMENT_GAP_S` the motion is unknown: the sweep is kept at the last
        pose with the window's covariance, flagged ``new_segment``, and the stream starts afresh from it."""
        self._forget_motion()
        st.ref = Reference()
        st.append(st.poses[-1].copy(), sw.ts, 1)
        problem = stream_time.azimuth_count(sw.scan, st.azimuths)[1] or self.sweep_problem(sw.scan)
        if problem is None:
            self._make_reference(st, sw, None, len(st.poses) - 1)
        flags = {NEW_SEGMENT} if problem is None else {NEW_SEGMENT, DEGENERATE, problem}
        return Estimate(np.zeros(3), self._window_cov.copy(), sw.ts, frozenset(flags))

    def _make_reference(self, st: StreamState, sw: Sweep, twist, index: int) -> None:
        """The sweep at trajectory ``index`` becomes the reference, drawn with ``twist`` in its own frame."""
        st.ref = Reference(self._graph.first(self._input(sw, twist)), index, sw.scan, 0.0, twist)
        st.odometry_since_ref = (np.zeros(3), np.zeros((3, 3)))

    def _input(self, sw: Sweep, twist) -> np.ndarray:
        """The sweep's graph input: de-skewed with ``twist`` (which only the stream knows), else as prepared."""
        if twist is not None:
            return self._matcher.draw(sw.scan, SweepMotion(twist=twist))
        return self._matcher.draw(sw.scan) if sw.prepared is None else sw.prepared.input

    def _lead_s(self, index: int) -> float:
        """Seconds (in periods) from the end of the velocity's interval to the sweep at ``index``."""
        end = self._state.velocity_end_tick
        return 0.0 if end is None else max(0, self._state.ticks[index] - end) * self._period_s

    def _degenerate(self, st: StreamState, reason: str, ts: int, periods: int, odo_rel=None) -> Estimate:
        """The constant-velocity prediction (with external odometry fused in) and the window's covariance;
        the reference stays and the velocity is not updated."""
        pred = self._prior.predict(periods * self._period_s, self._lead_s(len(st.poses) - 1))
        rel = pred[0] if pred is not None else np.zeros(3)
        cov = self._window_cov.copy()
        if odo_rel is not None:
            rel, cov, _ = fuse_estimates(odo_rel[0], odo_rel[1], rel, cov)
        if st.odometry_since_ref is not None:
            st.odometry_since_ref = compose_relative(*st.odometry_since_ref, *odo_rel) if odo_rel is not None else None
        st.append(st.poses[-1] @ se2(*rel), ts, periods)
        flags = {DEGENERATE, reason} | ({GAP} if periods > 1 else set())
        return Estimate(np.array(rel, dtype=np.float64), cov, ts, frozenset(flags))
