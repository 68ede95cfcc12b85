"""`RadarOdometer`: radar odometry over a stream of sweeps with one exported ONNX graph.

    odo = RadarOdometer("model.onnx")
    for scan in sweeps:
        est = odo.step(scan)          # None for the first sweep of a stream
    odo.trajectory.poses              # float64[N, 3, 3] absolute poses, first sweep = identity

An `Estimate` is the pose of the new sweep expressed in the previous sweep's frame (Oxford
ground-truth convention, see `radar_odom.se2`) with its 3×3 covariance over (x, y, yaw).

Faults, and what the odometer does about them (never a NaN, never a broken trajectory):

- A sweep whose timestamp (first azimuth) does not increase → `StreamError`.
- Gaps (dropped sweeps, a stalled recorder): by default every gap up to `NEW_SEGMENT_GAP_S`
  (10 s) is crossed; beyond it (a clock reset) no prediction places the search window, so the
  sweep starts a new segment: kept at the last pose with the window's covariance, flagged
  ``"new_segment"``, the stream restarted from it. An interval
  longer than 1.5 nominal periods (the median of the last intervals) is a gap, and its
  estimate is flagged ``"gap"``. Where the reference sweep is that far back and the motion
  prior can predict the motion over the interval, the new sweep is drawn in the predicted frame
  (Cartesian models; the last velocity held as an arc), the graph measures the residual and the
  pose is the residual composed with the prediction, its covariance carried through
  (`radar_odom.odometry.gaps`; the crossing is `radar_odom.odometry.match_stage`'s): the ±window
  of the search is centred on the prediction instead of on standing still. The crossing is matched
  from nine centres around the prediction (and again on each sharp reading) and taken only where
  two readings agree within the gap's prior; else the estimate is the prediction with a covariance
  that grows with the gap, flagged ``"gated"`` (docs/gaps.md). With ``max_gap_s`` set, a longer gap
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

import numpy as np

from ..errors import ConfigError, InputTypeError, ModelMismatchError
from ..onnx_model import OnnxModel
from ..scan import RadarScan
from ..se2 import invert, se2, to_xyyaw
from . import gaps, stream_time, whole_periods
from .arguments import config_number, stream_timestamp
from .deskew_stage import DESKEW_STEPS, DeskewStage  # noqa: F401  (DESKEW_STEPS re-exported: its home was here)
from .estimate import BRIDGED, DEGENERATE, Estimate, PreparedSweep, Trajectory, window_covariance  # noqa: F401
from .gaps import GAP, NEW_SEGMENT, NEW_SEGMENT_GAP_S, SweepPeriod
from .graph_step import GraphStep
from .match_stage import MatchStage
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

# De-skew is on by default only where it measured better on real drives (README, real-drive table)
DESKEW_DEFAULT = False
CENTRE_YAW_DEFAULT = False  # `radar_odom.odometry.centring`; None in the constructor reads this
# what step()/prepare() say to a caller passing an array: how to make the sweep they take
SCAN_HINT = ("wrap the sweep first: RadarScan.from_arrays(timestamps_us, azimuths_rad, power, "
             "range_resolution_m=...) for arrays, radar_odom.load_scan(path) for a file")


def _is_loaded_model(model) -> bool:
    """True for a model object with `OnnxModel`'s interface (``info``, ``path``, ``run``) rather than a path."""
    return all(hasattr(model, a) for a in ("info", "path", "run")) and callable(model.run)


class RadarOdometer:
    """Odometry with an exported radar-odom ONNX model, configured from its metadata.

    Args:
        model: path of the ``.onnx`` file (e.g. ``radar_odom.pretrained("cart-0.4")``), any form but the
            sequence's (a sweep-form file draws the Cartesian image in its graph: no de-skew, gap crossing or
            yaw centring, which draw it moved), or a loaded model (`OnnxModel`, `radar_odom.runtimes.OpenVinoModel`).
        threads: onnxruntime intra-op threads; default: the number of physical cores.
        providers: onnxruntime execution providers; default CPU.
        max_gap_s: None (default): every gap is crossed (see "Gaps" in the module docstring);
            a number (s): a larger time between consecutive sweeps is a hard stop, ``on_gap``.
        on_gap: beyond ``max_gap_s``: ``"raise"`` (`StreamError`) or ``"reset"`` (start a new
            stream).
        min_valid_fraction: below this fraction of valid azimuth rows a sweep is degenerate.
        min_coverage: below this fraction of the turn covered by valid azimuths a sweep is
            degenerate (``"partial_coverage"``, see `sweep_problem`).
        motion_prior: True (default: `MotionPriorConfig()`), False (off), or a
            `MotionPriorConfig`: fuse each match with a constant-velocity prediction (see the
            module docstring and `radar_odom.odometry.motion_prior`).
        deskew: de-skew both sweeps of each match with one velocity of the motion so far
            (constant over the sweep) before matching, so that the pose refers to the two sweeps'
            first-azimuth instants (Cartesian models; `radar_odom.odometry.deskew_stage`).
            ``reference_redraws`` counts the graph calls spent redrawing a reference.
        deskew_gaps: True (default): a gap crossing the readings agree on is matched again with both
            sweeps de-skewed by the crossing's own velocity (over a gap the sweeps' motion distortion
            does not cancel as between consecutive ones; `MatchStage.deskew_crossing`, docs/gaps.md);
            four more graph calls per agreed crossing. Independent of ``deskew``.
        sweep_period_s: the sensor's period (s) where known (``Sequence.time_base.period_s``, which
            `run_sequence` passes): an interval over 1.5 of it is a gap. None (default): 1.5 of the
            median of the last intervals (`radar_odom.odometry.gaps.SweepPeriod`).
        time_base: the recording's `radar_odom.io.timebase.TimeBase` (``Sequence.time_base``, which
            `run_sequence` passes): its period is ``sweep_period_s`` (unless given), and where its
            stamps cannot place a sweep (``TimeBase.alternatives``) the match decides the sweep's time
            (`radar_odom.odometry.whole_periods`); ``time_base`` then gives the decided one.

    Raises `ConfigError` (a ValueError) for an argument it cannot use (``max_gap_s`` or
    ``sweep_period_s`` NaN or ≤ 0, a fraction outside [0, 1], an unknown ``on_gap``); `InvalidModelError` for a corrupt
    model file or metadata (see `radar_odom.onnx_model`).

    Threads: `step`, `skip`, `reset` and `trajectory` are serialised by a lock held for the
    whole call, so one odometer stepped from several threads never interleaves the inside of
    two steps (its trajectory stays consistent). The *order* of the sweeps is then whichever
    thread takes the lock first: a sweep older than the last one taken raises `StreamError` as
    usual. A stream should be fed by one thread; use one odometer per stream for parallelism
    (they share nothing).
    """

    def __init__(self, model, threads: int | None = None, providers=None, max_gap_s: float | None = None,
                 on_gap: str = "raise", min_valid_fraction: float = 0.5,
                 motion_prior: bool | MotionPriorConfig = True, min_coverage: float = MIN_COVERAGE,
                 deskew: bool = DESKEW_DEFAULT, centre_yaw: bool | None = None, sweep_period_s: float | None = None,
                 time_base=None, deskew_gaps: bool = True):
        if on_gap not in ("raise", "reset"):
            raise ConfigError(f"on_gap must be 'raise' or 'reset', got {on_gap!r}")
        self.max_gap_s = None if max_gap_s is None else config_number(max_gap_s, "max_gap_s", low=0.0, open_low=True)
        for name, flag in (("deskew", deskew), ("deskew_gaps", deskew_gaps)):
            if not isinstance(flag, (bool, np.bool_)):
                raise ConfigError(f"{name} must be True or False, got {flag!r}")
        self.min_valid_fraction = config_number(min_valid_fraction, "min_valid_fraction", low=0.0, high=1.0)
        self.min_coverage = config_number(min_coverage, "min_coverage", low=0.0, high=1.0)
        if isinstance(motion_prior, MotionPriorConfig):
            config, use = motion_prior, True
        elif isinstance(motion_prior, (bool, np.bool_)):
            config, use = MotionPriorConfig(), bool(motion_prior)
        else:
            raise TypeError(f"motion_prior must be True, False or a MotionPriorConfig, got {motion_prior!r}")
        self._use_prediction = use
        self._prior = MotionPrior(config)
        # an OnnxModel, or a model on another runtime with its interface (`radar_odom.runtimes.OpenVinoModel`)
        self._model = model if isinstance(model, OnnxModel) or _is_loaded_model(model) else OnnxModel(
            model, threads, providers)
        self.info = self._model.info
        self._graph = GraphStep(self._model)
        if self.info.form == "sequence":
            raise ModelMismatchError(
                f"{self._model.path.name} is a sequence-form model (offline batches of consecutive sweeps); "
                "use radar_odom.match_sequence with it, or a stream-form model (radar_odom.pretrained) here"
            )
        self.profile = self.info.profile
        self.on_gap = on_gap
        self._prior_cov = window_covariance(self.profile)
        self._lock = threading.RLock()
        self.sweep_region_m = model_region_m(self.info)
        # a polar model's graph reads the sweep as recorded, a sweep-form graph draws it as recorded: neither
        # de-skew nor a moved frame (nor the gap crossing and yaw centring, which draw the sweep moved)
        self._movable = self.profile.input_kind != "polar" and self.info.form != "sweep"
        # the de-skew stage: which twist a match's sweeps are drawn with; the graph call to redraw stays here
        self._deskew_stage = DeskewStage(bool(deskew) and self._movable, self.profile, self.info.mount_yaw_rad,
                                         self._redraw_reference)
        if centre_yaw is None:
            centre_yaw = CENTRE_YAW_DEFAULT
        if not isinstance(centre_yaw, (bool, np.bool_)):
            raise ConfigError(f"centre_yaw must be True, False or None, got {centre_yaw!r}")
        # the sensor's period where known (a recording's time base): a gap is then > 1.5 of it, not of a median
        self._times = whole_periods.SweepTimes(time_base)
        self._period_from_base = sweep_period_s is None  # the time base's period, which a sweep's turn may refine
        if sweep_period_s is None:
            sweep_period_s = self._times.period_s
        self._period = SweepPeriod(known_s=None if sweep_period_s is None else config_number(
            sweep_period_s, "sweep_period_s", low=0.0, open_low=True))
        # the predict and match stages (a gap crossed, the yaw centred); the graph calls stay here
        self._match_stage = MatchStage(
            self.profile, self.info.mount_yaw_rad, self._movable, bool(centre_yaw) and self._movable, self._period,
            self._prior, lambda x, keep_reference=False: self._run_pair(x, keep_reference),
            self._run_first, lambda scan, motion=None: self._sweep_input(scan, motion),
            run_against=lambda x, reference: self._graph.match(x, reference, True), deskew_gaps=bool(deskew_gaps))
        self.reset()

    @property
    def path(self):
        return self._model.path

    @property
    def time_base(self):
        """The recording's time base with the sweep times the match decided (`TimeBase.decided`), or None."""
        with self._lock:
            return self._times.time_base

    @property
    def motion_prior(self) -> MotionPriorConfig | None:
        """The motion prior's configuration, or None when it is off."""
        return self._prior.config if self._use_prediction else None

    @property
    def deskew(self) -> bool:
        """De-skew on (the constructor's ``deskew``; False for a model whose sweeps cannot be drawn moved)."""
        return self._deskew_stage.enabled

    @property
    def centre_yaw(self) -> bool:
        """Yaw centring on (the constructor's ``centre_yaw``; False for a model whose sweeps cannot be drawn moved)."""
        return self._match_stage.centre_yaw

    @property
    def reference_redraws(self) -> int:
        """Graph calls spent redrawing a reference for de-skew (this stream; `DeskewStage.redraws`)."""
        return self._deskew_stage.redraws

    def reset(self) -> None:
        """Forget the stream: the next sweep starts a new trajectory at identity."""
        with self._lock:
            self._reset()

    def _reset(self) -> None:
        self._poses: list[np.ndarray] = []
        self._stamps: list[int] = []
        self._ref_feed: np.ndarray | None = None  # state (stream form) or sweep input (pair form)
        self._ref_index = -1  # trajectory index of the sweep ``_ref_feed`` belongs to
        self._ref_turn = 0.0  # turn (rad) the reference was drawn with (`radar_odom.odometry.centring`)
        self._ref_scan: RadarScan | None = None  # the reference sweep as recorded (a gap crossing redraws it)
        self._deskew_stage.reset()  # the reference as recorded, its twist, the motion de-skew averages
        self._forget_motion()
        self._times.reset()  # the sweep times the match decided
        self._range_scale: tuple | None = None  # (range resolution m, offset m) of the stream's sweeps
        self._azimuths: int | None = None  # azimuth rows of the stream's sweeps (its first one's)

    def _forget_motion(self) -> None:
        """Forget how the stream moved (a new stream, or a new segment after a stamp jump)."""
        self._prior.reset()  # velocity (also tracked with the prior off: degenerate sweeps use it)
        self._velocity_end_us: int | None = None  # timestamp at the end of the velocity's interval
        # external odometry from the reference sweep to the latest one, (pose, cov); None if unknown
        self._odometry_since_ref: tuple | None = None
        self._period.reset()
        self._deskew_stage.forget_motion()

    @property
    def trajectory(self) -> Trajectory:
        with self._lock:
            if not self._poses:
                return Trajectory(np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64))
            return Trajectory(np.stack(self._poses), np.asarray(self._stamps, dtype=np.int64))

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
                self._append(np.eye(3), ts)
                return None
            dt_s = (ts - self._stamps[-1]) * 1e-6
            return self._degenerate(str(reason), ts, dt_s, flags=self._interval_flags(dt_s))

    def _check_time(self, ts: int, source: str) -> bool:
        """`StreamError` unless ``ts`` may follow the stream (resets it on a gap with
        ``on_gap="reset"``); True when ``ts`` starts a new stream."""
        if self._stamps:
            dt_s = stream_time.interval_s(ts, self._stamps[-1], source)
            if self.max_gap_s is not None and dt_s > self.max_gap_s:
                if self.on_gap != "reset":
                    raise stream_time.beyond_max_gap(source, dt_s, self.max_gap_s)
                self._reset()
        return not self._stamps

    def _step(self, scan: RadarScan, odometry, prepared: PreparedSweep | None = None) -> Estimate | None:
        """One sweep through the stages (`radar_odom.odometry` names each stage's home)."""
        # time: in order after the stream, the same range bins; a new stream, a new segment, or an interval
        self._check_geometry(scan)
        ts = scan.timestamp_us
        first = self._check_time(ts, scan.source)
        self._check_range_scale(scan, first)
        # sweep checks: can the model read it at all (the stream's azimuth rows first: the others judge it alone)
        self._azimuths, problem = stream_time.azimuth_count(scan, None if first else self._azimuths)
        problem = problem or (self.sweep_problem(scan) if prepared is None else prepared.problem)
        if first:
            return self._start_stream(scan, prepared, problem, ts)
        dt_s = (ts - self._stamps[-1]) * 1e-6
        if self.max_gap_s is None and dt_s > NEW_SEGMENT_GAP_S:
            return self._new_segment(scan, prepared, problem, ts)
        if problem is None:  # whole periods the stamps cannot tell: the match decides the sweep's time
            ts = self._sweep_time(scan, ts)
            dt_s = (ts - self._stamps[-1]) * 1e-6
        flags = self._interval_flags(dt_s)
        odo_rel = odometry.relative_pose(dt_s) if odometry is not None else None
        if problem is not None:
            return self._degenerate(problem, ts, dt_s, odo_rel, flags)
        if self._ref_feed is None:
            return self._first_reference(scan, prepared, ts, dt_s, odo_rel, flags)
        # graph input: drawn with the reference's twist (de-skew stage), else as prepared
        twist = self._deskew_stage.pair_twist(scan)
        x = self._input(scan, prepared, twist)
        # predict and match: against the reference; across a gap, from the prediction; a de-skewed
        # stream's first match drawn again with the velocity it measured
        out = self._match(scan, x, ts, twist)
        out, twist = self._deskew_stage.first_match(
            scan, (ts - self._stamps[self._ref_index]) * 1e-6, out, twist,
            lambda drawn: self._match(scan, self._input(scan, None, drawn), ts, drawn))
        if out is None:
            return self._degenerate("nonfinite", ts, dt_s, odo_rel, flags)
        # fuse with the prior and chain onto the trajectory; the new sweep becomes the reference
        pose_ref, cov, new_ref, new_turn = out[:4]
        flags |= out[4] if len(out) > 4 else set()  # a gap crossing's verdict (`MatchStage.cross_gap`)
        est = self._accept(pose_ref, cov, new_ref, ts, dt_s, odo_rel, flags, ref_turn=new_turn)
        self._deskew_stage.keep_reference(scan, twist)
        self._ref_scan = scan
        return est

    def _start_stream(self, scan: RadarScan, prepared, problem, ts: int) -> None:
        """A stream's first sweep, recorded at identity. A stream must start from a sweep that can be
        matched: a degenerate first sweep is recorded but never becomes the reference."""
        if self._times.adopt_rotation(scan) and self._period_from_base:  # its own turn picked the period
            self._period.known_s = self._times.period_s
        if problem is None:
            self._make_reference(scan, prepared, None, 0)  # no velocity yet
        self._append(np.eye(3), ts)
        return None

    def _first_reference(self, scan: RadarScan, prepared, ts: int, dt_s: float, odo_rel, flags) -> Estimate:
        """Every earlier sweep of the stream was degenerate: nothing to match against yet, so this
        one gets the prior's pose (flagged ``no_reference``) and becomes the reference."""
        twist = self._deskew_stage.stream_twist(scan)
        est = self._degenerate("no_reference", ts, dt_s, odo_rel, flags)
        self._make_reference(scan, prepared, twist, len(self._poses) - 1)
        return est

    def _make_reference(self, scan: RadarScan, prepared, twist, index: int) -> None:
        """Make the sweep at trajectory ``index`` the reference, drawn with ``twist`` in its own frame."""
        self._ref_feed = self._run_first(self._input(scan, prepared, twist))
        self._ref_turn = 0.0
        self._deskew_stage.keep_reference(scan, twist)
        self._ref_scan = scan
        self._set_reference(index)

    # --- pieces ---------------------------------------------------------------------------
    def _check_range_scale(self, scan: RadarScan, first: bool) -> None:
        """`StreamError` where the stream's range bins change (`stream_time.range_bins`)."""
        self._range_scale = stream_time.range_bins(scan, None if first else self._range_scale)

    def _new_segment(self, scan: RadarScan, prepared, problem, ts: int) -> Estimate:
        """After a stamp jump beyond `NEW_SEGMENT_GAP_S`: the motion over it is unknown, so the sweep
        is placed at the last pose with the search window's covariance, flagged ``new_segment``,
        and the stream starts afresh from it (velocity, period and de-skew history forgotten)."""
        self._forget_motion()
        self._ref_feed = None
        self._ref_turn = 0.0
        self._append(self._poses[-1].copy(), ts)
        if problem is None:
            self._make_reference(scan, prepared, None, len(self._poses) - 1)
        flags = {NEW_SEGMENT} if problem is None else {NEW_SEGMENT, DEGENERATE, problem}
        return Estimate(np.zeros(3), self._prior_cov.copy(), ts, frozenset(flags))

    def _check_geometry(self, scan: RadarScan) -> None:
        check_sweep_geometry(scan, self.info, self.path.name)

    def _sweep_input(self, scan: RadarScan, motion: SweepMotion | None = None) -> np.ndarray:
        return graph_input(scan, self.info, motion)

    def _redraw_reference(self, ref_scan: RadarScan, twist) -> bool:
        """The de-skew stage's graph call: the reference sweep drawn again with ``twist`` (and its turn)
        becomes the reference; False (the reference kept) where the graph's output is not finite."""
        feed = self._match_stage.draw_reference(ref_scan, twist, self._ref_turn)
        if feed is None:
            return False
        self._ref_feed = feed
        return True

    def _interval_flags(self, dt_s: float) -> set:
        """{"gap"} when ``dt_s`` (since the previous sweep) is a gap, else empty; then the interval
        joins the nominal period's history."""
        flags = {GAP} if self._period.is_gap(dt_s) else set()
        self._period.observe(dt_s)
        return flags

    def _input(self, scan: RadarScan, prepared: PreparedSweep | None, twist) -> np.ndarray:
        """The graph input of the sweep as the stream takes it: de-skewed when that is on (the
        prepared image is drawn without the velocity, which only the stream knows); ``twist``:
        `DeskewStage.pair_twist`'s, or None."""
        if twist is not None:
            return self._sweep_input(scan, SweepMotion(twist=twist))
        return self._sweep_input(scan) if prepared is None else prepared.input

    def _match(self, scan: RadarScan, x: np.ndarray, ts: int, twist):
        """The predict and match stages (`MatchStage.match`): (pose, cov, new reference, its turn[, flags])
        of the new sweep against the reference, or None if non-finite."""
        ref_ts = self._stamps[self._ref_index]
        return self._match_stage.match(scan, x, twist, (ts - ref_ts) * 1e-6, self._lead_s(ref_ts), self._ref_turn,
                                       ref_scan=self._ref_scan)

    def _sweep_time(self, scan: RadarScan, ts: int) -> int:
        """The time stage's whole periods: where the stamps cannot place this sweep (a drop before it,
        or its stamp a period late and the drop after it), its time from the match
        (`whole_periods.decide_time`); the time base's time where they can, or where nothing can decide
        (no reference, no velocity, a model whose sweeps cannot be drawn moved, no clear lead); ``ts``
        for a sweep not in the time base."""
        options = self._times.options(ts, self._stamps[-1])
        if not options:  # not a sweep of the time base (or none given): its own time
            return ts
        if len(options) < 2 or self._ref_feed is None or not self._movable or not self._prior.ready:
            return options[0][1]  # the fit's
        ref_ts, twist = self._stamps[self._ref_index], self._deskew_stage.ref_twist  # None with de-skew off
        stage = self._match_stage
        chosen, _ = whole_periods.decide_time(
            [t for _, t in options], ref_ts, stage.prior_step(), self._lead_s(ref_ts),
            lambda pose: stage.readings_around(scan, twist, pose, self._ref_turn) or [], gaps.agreement(self.profile))
        return options[0][1] if chosen is None else self._times.decide(ts, options[chosen][0])

    def _run_first(self, x: np.ndarray) -> np.ndarray:
        """The reference state of a sweep with graph input ``x`` (`GraphStep.first`)."""
        return self._graph.first(x)

    def _run_pair(self, x: np.ndarray, keep_reference: bool = False):
        """(pose, cov, new reference) of ``x`` against the current reference, or None (`GraphStep.match`)."""
        return self._graph.match(x, self._ref_feed, keep_reference)

    def _set_reference(self, index: int) -> None:
        self._ref_index = index
        self._odometry_since_ref = (np.zeros(3), np.zeros((3, 3)))

    def _lead_s(self, start_us: int) -> float:
        """Seconds from the end of the velocity's interval to ``start_us``."""
        return 0.0 if self._velocity_end_us is None else max(0.0, (start_us - self._velocity_end_us) * 1e-6)

    def _accept(self, pose_ref, cov, new_ref, ts, dt_s, odo_rel=None, flags=None, ref_turn: float = 0.0) -> Estimate:
        """A good match of the new sweep against the reference sweep, fused with the prior."""
        ref_pose, ref_ts = self._poses[self._ref_index], self._stamps[self._ref_index]
        bridged = self._ref_index != len(self._poses) - 1
        # external odometry over the match's interval (reference sweep → new sweep)
        odo_interval = None
        if odo_rel is not None and self._odometry_since_ref is not None:
            odo_interval = compose_relative(*self._odometry_since_ref, *odo_rel)
        flags = set(flags or ())
        if self._use_prediction or odo_interval is not None:
            res = self._prior.update(pose_ref, cov, (ts - ref_ts) * 1e-6, self._lead_s(ref_ts),
                                     odometry=odo_interval, use_prediction=self._use_prediction)
            fused, fused_cov = res.pose, res.covariance
            flags |= res.flags
            if GATED not in res.flags:
                self._velocity_end_us = ts
        else:
            fused, fused_cov = pose_ref, cov
        absolute = ref_pose @ se2(*fused)
        if not bridged:
            rel, meas, meas_cov = fused, pose_ref, cov
        else:  # bridged across degenerate sweeps: re-express against the previous (prior) pose
            to_prev = invert(self._poses[-1])
            rel = to_xyyaw(to_prev @ absolute)
            meas = to_xyyaw(to_prev @ ref_pose @ se2(*pose_ref))
            fused_cov = fused_cov + self._prior_cov
            meas_cov = cov + self._prior_cov
            flags.add(BRIDGED)
        if not (self._use_prediction or odo_interval is not None):
            # no fusion: the velocity follows the reported steps, as it always did
            self._prior.observe(rel, fused_cov, dt_s)
            self._velocity_end_us = ts
        self._ref_feed = new_ref
        self._ref_turn = float(ref_turn)
        if GATED not in flags:
            self._deskew_stage.observe(rel, dt_s)
        self._append(absolute, ts)
        self._set_reference(len(self._poses) - 1)
        return Estimate(np.asarray(rel, dtype=np.float64), fused_cov, ts, frozenset(flags),
                        np.array(meas, dtype=np.float64), np.array(meas_cov, dtype=np.float64))

    def _degenerate(self, reason: str, ts: int, dt_s: float, odo_rel=None, flags=None) -> Estimate:
        """Constant-velocity prediction with the search window's covariance; the reference stays.

        With external odometry, that is fused in (information form). The velocity is not updated.
        """
        pred = self._prior.predict(dt_s, self._lead_s(self._stamps[-1]))
        rel = pred[0] if pred is not None else np.zeros(3)
        cov = self._prior_cov.copy()
        if odo_rel is not None:
            rel, cov, _ = fuse_estimates(odo_rel[0], odo_rel[1], rel, cov)
        if self._odometry_since_ref is not None:
            self._odometry_since_ref = (compose_relative(*self._odometry_since_ref, *odo_rel)
                                        if odo_rel is not None else None)
        self._append(self._poses[-1] @ se2(*rel), ts)
        return Estimate(np.array(rel, dtype=np.float64), cov, ts, frozenset({DEGENERATE, reason, *(flags or ())}))

    def _append(self, absolute: np.ndarray, ts: int) -> None:
        self._poses.append(absolute)
        self._stamps.append(int(ts))
