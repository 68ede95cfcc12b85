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
  (`radar_odom.odometry.gaps`): the ±window of the search is centred on the prediction instead of
  on standing still. The crossing is matched from nine centres around the prediction (and again
  on each sharp reading) and taken only where two readings agree within the gap's prior; else the
  estimate is the prediction with a covariance that grows with the gap, flagged ``"gated"``
  (docs/gaps.md). With ``max_gap_s`` set, a
  longer gap is a hard stop instead: ``on_gap="raise"`` (default) raises `StreamError` (call
  `reset()` and go on); ``on_gap="reset"`` resets the stream itself, so that sweep starts a
  new trajectory at identity and `step` returns None.
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

Motion compensation (``deskew=True``; Cartesian models). A spinning radar takes a whole period
per sweep, so at 10 m/s the scene shifts 2.5 m between its first and last azimuth. With de-skew
on, each sweep is drawn as seen from the sensor at its first azimuth's instant
(``scan.timestamp_us``), every azimuth moved by the velocity of the motion so far (the mean
of the last ``DESKEW_STEPS`` estimates, constant over the sweep, from each row's timestamp:
Oxford and Boreas carry them, RADIATE's are spread uniformly over the period;
`radar_odom.polar.moving_sample_maps`).
Poses then refer to the first-azimuth instants of the two sweeps, so both sweeps of a match are
drawn with the same twist: the reference is kept as recorded and redrawn (one extra graph call)
when the stream's velocity has moved away from the twist it was drawn with
(`radar_odom.odometry.sweep_input.twists_differ`); otherwise the new sweep takes the reference's
twist. A stream's first match has no velocity yet: it is made as recorded, its pose over its
interval gives the velocity, and the pair is drawn again with it and matched again (two extra
graph calls, once per stream).

Yaw centring (``centre_yaw=True``; Cartesian models; off by default): each sweep drawn turned by
the predicted yaw, so the pull of the pixel grids goes toward the prediction rather than toward
"no rotation" (`radar_odom.odometry.centring`; measured in docs/yaw-precision.md: simulated bends
read more fully, the real drive worse, hence off).
"""
from __future__ import annotations

import threading
from collections import deque

import numpy as np

from ..errors import ConfigError, InputTypeError, ModelMismatchError
from ..onnx_model import OnnxModel
from ..scan import RadarScan
from ..se2 import invert, se2, to_xyyaw, turn_frame
from . import gaps, stream_time
from .arguments import config_number, stream_timestamp
from .centring import MAX_TURN_RAD, next_turn, uncentre
from .estimate import BRIDGED, DEGENERATE, Estimate, PreparedSweep, Trajectory, window_covariance  # noqa: F401
from .gaps import GAP, NEW_SEGMENT, NEW_SEGMENT_GAP_S, SweepPeriod
from .graph_step import GraphStep
from .motion_prior import GATED, PRIOR_DOMINATED, ExternalOdometry, MotionPrior, MotionPriorConfig
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
from .sweep_input import SweepMotion, deskew_twist, graph_input, twists_differ

# De-skew is on by default only where it measured better on real drives (README, real-drive table)
DESKEW_DEFAULT = False
CENTRE_YAW_DEFAULT = False  # `radar_odom.odometry.centring`; None in the constructor reads this
# what step()/prepare() say to a caller passing an array: how to make the sweep they take
SCAN_HINT = ("wrap the sweep first: RadarScan.from_arrays(timestamps_us, azimuths_rad, power, "
             "range_resolution_m=...) for arrays, radar_odom.load_scan(path) for a file")
DESKEW_STEPS = 4  # estimates averaged into the de-skew velocity (1 s at 4 Hz)


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
            first-azimuth instants (Cartesian models; see "Motion compensation" in the module
            docstring). ``reference_redraws`` counts the graph calls spent redrawing a reference.
        sweep_period_s: the sensor's period (s) where known (``Sequence.time_base.period_s``, which
            `run_sequence` passes): an interval over 1.5 of it is a gap. None (default): 1.5 of the
            median of the last intervals (`radar_odom.odometry.gaps.SweepPeriod`).

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
                 deskew: bool = DESKEW_DEFAULT, centre_yaw: bool | None = None, sweep_period_s: float | None = None):
        if on_gap not in ("raise", "reset"):
            raise ConfigError(f"on_gap must be 'raise' or 'reset', got {on_gap!r}")
        self.max_gap_s = None if max_gap_s is None else config_number(max_gap_s, "max_gap_s", low=0.0, open_low=True)
        if not isinstance(deskew, (bool, np.bool_)):
            raise ConfigError(f"deskew must be True or False, got {deskew!r}")
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
        self.deskew = bool(deskew) and self._movable
        if centre_yaw is None:
            centre_yaw = CENTRE_YAW_DEFAULT
        if not isinstance(centre_yaw, (bool, np.bool_)):
            raise ConfigError(f"centre_yaw must be True, False or None, got {centre_yaw!r}")
        self.centre_yaw = bool(centre_yaw) and self._movable
        # the sensor's period where known (a recording's time base): a gap is then > 1.5 of it, not of a median
        self._period = SweepPeriod(known_s=None if sweep_period_s is None else config_number(
            sweep_period_s, "sweep_period_s", low=0.0, open_low=True))
        self.reset()

    @property
    def path(self):
        return self._model.path

    @property
    def motion_prior(self) -> MotionPriorConfig | None:
        """The motion prior's configuration, or None when it is off."""
        return self._prior.config if self._use_prediction else None

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
        self._ref_scan: RadarScan | None = None  # the reference as recorded, redrawn when de-skew needs it
        self._ref_twist: tuple | None = None  # the de-skew twist the reference was drawn with
        self.reference_redraws = 0  # graph calls spent redrawing a reference for de-skew (this stream)
        self._recent_motion: deque = deque(maxlen=DESKEW_STEPS)  # (relative pose, interval s)
        self._forget_motion()
        self._range_scale: tuple | None = None  # (range resolution m, offset m) of the stream's sweeps
        self._azimuths: int | None = None  # azimuth rows of the stream's sweeps (its first one's)

    def _forget_motion(self) -> None:
        """Forget how the stream moved (a new stream, or a new segment after a stamp jump)."""
        self._prior.reset()  # velocity (also tracked with the prior off: degenerate sweeps use it)
        self._velocity_end_us: int | None = None  # timestamp at the end of the velocity's interval
        # external odometry from the reference sweep to the latest one, (pose, cov); None if unknown
        self._odometry_since_ref: tuple | None = None
        self._period.reset()
        self._recent_motion.clear()

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
        flags = self._interval_flags(dt_s)
        odo_rel = odometry.relative_pose(dt_s) if odometry is not None else None
        if problem is not None:
            return self._degenerate(problem, ts, dt_s, odo_rel, flags)
        if self._ref_feed is None:
            return self._first_reference(scan, prepared, ts, dt_s, odo_rel, flags)
        # graph input: drawn with the reference's twist (de-skew), else as prepared
        twist = self._pair_twist(scan)
        x = self._input(scan, prepared, twist)
        # predict and match: against the reference; across a gap, from the prediction
        out = self._match(scan, x, ts, twist)
        if out is not None and twist is None and self.deskew and not self._recent_motion:
            out, twist = self._match_deskewed_first(scan, ts, out)
        if out is None:
            return self._degenerate("nonfinite", ts, dt_s, odo_rel, flags)
        # fuse with the prior and chain onto the trajectory; the new sweep becomes the reference
        pose_ref, cov, new_ref, new_turn = out[:4]
        flags |= out[4] if len(out) > 4 else set()  # a gap crossing's verdict (`_cross_gap`)
        est = self._accept(pose_ref, cov, new_ref, ts, dt_s, odo_rel, flags, ref_turn=new_turn)
        self._keep_reference(scan, twist)
        return est

    def _start_stream(self, scan: RadarScan, prepared, problem, ts: int) -> None:
        """A stream's first sweep, recorded at identity. A stream must start from a sweep that can be
        matched: a degenerate first sweep is recorded but never becomes the reference."""
        if problem is None:
            self._make_reference(scan, prepared, None, 0)  # no velocity yet
        self._append(np.eye(3), ts)
        return None

    def _first_reference(self, scan: RadarScan, prepared, ts: int, dt_s: float, odo_rel, flags) -> Estimate:
        """Every earlier sweep of the stream was degenerate: nothing to match against yet, so this
        one gets the prior's pose (flagged ``no_reference``) and becomes the reference."""
        twist = self._deskew_twist(scan)
        est = self._degenerate("no_reference", ts, dt_s, odo_rel, flags)
        self._make_reference(scan, prepared, twist, len(self._poses) - 1)
        return est

    def _make_reference(self, scan: RadarScan, prepared, twist, index: int) -> None:
        """Make the sweep at trajectory ``index`` the reference, drawn with ``twist`` in its own frame."""
        self._ref_feed = self._run_first(self._input(scan, prepared, twist))
        self._ref_turn = 0.0
        self._keep_reference(scan, twist)
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

    def _deskew_twist(self, scan: RadarScan):
        """The velocity to de-skew ``scan`` with, or None: the mean over the last
        ``DESKEW_STEPS`` estimates (pose / interval). The last step alone feeds back: a yaw
        error de-skews the next sweep wrongly, which errs the next yaw the other way (measured
        on the shared RADIATE drive: per-step yaw error 1.58° with one step, 0.49° with four,
        0.48° without de-skew)."""
        if not self.deskew or not self._recent_motion:
            return None
        poses = np.array([m[0] for m in self._recent_motion])
        seconds = sum(m[1] for m in self._recent_motion)
        return self._radar_twist(poses.sum(axis=0) / seconds, scan)

    def _radar_twist(self, velocity, scan: RadarScan):
        """`deskew_twist` of a velocity (x m/s, y m/s, yaw rad/s) in the vehicle's frame, the frame
        estimates are reported in: turned into the radar's by the model's mount yaw."""
        radar = turn_frame(np.asarray(velocity, dtype=np.float64), None, -self.info.mount_yaw_rad)[0]
        return deskew_twist(radar, scan, self.profile)

    def _pair_twist(self, scan: RadarScan):
        """The twist the new sweep is drawn with, the one the reference was drawn with: the
        stream's (`_deskew_twist`) once that has moved away from the reference's (the reference
        redrawn with it, one graph call), else the reference's."""
        want = self._deskew_twist(scan)
        if not self.deskew or self._ref_scan is None or not twists_differ(want, self._ref_twist, scan, self.profile):
            return self._ref_twist if self.deskew else None
        return want if self._redraw_reference(want) else self._ref_twist

    def _redraw_reference(self, twist) -> bool:
        """Draw the reference sweep again with ``twist`` (and its turn) and make it the reference;
        False (the reference kept) where the graph's output is not finite."""
        turn = (0.0, 0.0, self._ref_turn) if self._ref_turn else None
        feed = self._run_first(self._sweep_input(self._ref_scan, SweepMotion(twist=twist, frame_pose=turn)))
        self.reference_redraws += 1
        if not np.all(np.isfinite(feed)):
            return False
        self._ref_feed, self._ref_twist = feed, twist
        return True

    def _match_deskewed_first(self, scan: RadarScan, ts: int, out):
        """(match, twist) of a stream's first match with de-skew on: ``out``, made as recorded,
        gives the velocity over its interval; the reference and the new sweep are drawn with it
        and matched again (two graph calls). ``out`` and None where that velocity moves no pixel;
        (None, None) where the second match is not finite (the reference then stays redrawn)."""
        interval_s = (ts - self._stamps[self._ref_index]) * 1e-6
        twist = self._radar_twist(np.asarray(out[0]) / interval_s, scan)
        if twist is None or not self._redraw_reference(twist):
            return out, None
        again = self._match(scan, self._input(scan, None, twist), ts, twist)
        return (again, twist) if again is not None else (None, None)

    def _keep_reference(self, scan: RadarScan, twist) -> None:
        """Remember the new reference sweep as recorded and the twist it was drawn with (de-skew
        redraws it when the stream's velocity moves away from that twist)."""
        self._ref_scan, self._ref_twist = (scan, twist) if self.deskew else (None, None)

    def _interval_flags(self, dt_s: float) -> set:
        """{"gap"} when ``dt_s`` (since the previous sweep) is a gap, else empty; then the interval
        joins the nominal period's history."""
        flags = {GAP} if self._period.is_gap(dt_s) else set()
        self._period.observe(dt_s)
        return flags

    def _input(self, scan: RadarScan, prepared: PreparedSweep | None, twist) -> np.ndarray:
        """The graph input of the sweep as the stream takes it: de-skewed when that is on (the
        prepared image is drawn without the velocity, which only the stream knows); ``twist``:
        `_deskew_twist`'s, or None."""
        if twist is not None:
            return self._sweep_input(scan, SweepMotion(twist=twist))
        return self._sweep_input(scan) if prepared is None else prepared.input

    def _match(self, scan: RadarScan, x: np.ndarray, ts: int, twist):
        """The predict and match stages: (pose, cov, new reference, its turn[, flags]) of the new sweep
        against the reference, or None if non-finite.

        Where the reference is further back than a gap (`radar_odom.odometry.gaps`) and the prior can
        predict the motion over it, the gap is crossed from the prediction (`_cross_gap`). Otherwise
        one match (`_match_plain`; with ``centre_yaw`` the sweep drawn turned by the predicted yaw).
        Poses leave here in the vehicle's frame: a model with a mount yaw
        (``ModelInfo.mount_yaw_rad``, `radar-odom adapt`) has its matches turned by it.
        """
        ref_ts = self._stamps[self._ref_index]
        interval_s = (ts - ref_ts) * 1e-6
        if self._movable and self._period.is_gap(interval_s) and self._prior.ready:
            # the last velocity held as a constant twist over the gap (an arc), its covariance grown with it
            pred = gaps.crossing_prior(self._prior.velocity * self._prior.interval_s,
                                       self._prior.velocity_covariance * self._prior.interval_s ** 2,
                                       self._prior.interval_s, interval_s, self._lead_s(ref_ts))
            if pred is not None:
                return self._cross_gap(scan, x, twist, pred)
        return self._match_plain(scan, x, twist, interval_s, ref_ts)

    def _match_plain(self, scan: RadarScan, x: np.ndarray, twist, interval_s: float, ref_ts: int):
        """(pose, cov, new reference, its turn) of one match of the new sweep against the reference
        (drawn turned by the predicted yaw with ``centre_yaw``), or None if non-finite."""
        if self.centre_yaw:
            out = self._match_centred(scan, x, twist, interval_s, ref_ts)
            if out is None:
                return None
        else:
            out = self._run_pair(x)
            if out is None:
                return None
            out = (*out, 0.0)  # without centring every reference is drawn at turn 0
        mount = self.info.mount_yaw_rad
        if not mount:
            return out
        return (*turn_frame(out[0], out[1], mount), out[2], out[3])

    def _cross_gap(self, scan: RadarScan, x: np.ndarray, twist, pred):
        """(pose, cov, new reference, 0.0[, flags]) of a sweep across a gap, ``pred`` the gap's prior
        (pose, cov): the sweep matched from several window centres around the prediction
        (`gaps.crossing_readings`); taken where readings agree within the prior (`gaps.consensus`,
        `gaps.crossing_d2`), else the prediction, flagged ``gated`` and ``prior_dominated``. None where no
        match is finite or the new reference is not. The new reference is the sweep in its own frame."""
        mount = self.info.mount_yaw_rad
        predicted = turn_frame(pred[0], None, -mount)[0]  # the prediction in the radar's frame
        # the reference was drawn turned by a_ref: draw the new sweep in R(a_ref)'s view of the prediction
        a_ref = self._ref_turn
        turned = to_xyyaw(se2(0.0, 0.0, -a_ref) @ se2(*predicted))

        def residual_at(centre):
            drawn = self._sweep_input(scan, SweepMotion(twist=twist, frame_pose=tuple(to_xyyaw(invert(se2(*centre))))))
            out = self._run_pair(drawn, keep_reference=True)
            return None if out is None else out[:2]

        readings = gaps.crossing_readings(turned, residual_at, self.profile)
        if readings is None:
            return None
        crossed = [turn_frame(*uncentre(*m, a_ref, 0.0), mount) for m in readings]
        new_ref = self._run_first(x)
        if not np.all(np.isfinite(new_ref)):
            return None
        tol_m, tol_rad, sharp_m = gaps.agreement(self.profile)
        agreed = gaps.consensus([c[0] for c in crossed], [c[1] for c in crossed], tol_m, tol_rad, sharp_m, prior=pred)
        if agreed is None or gaps.crossing_d2(agreed[0], agreed[1], *pred) > self._prior.config.gate_d2:
            # no centre agreed, or they agree on a motion the gap's prior rules out: keep the prediction
            return pred[0], pred[1], new_ref, 0.0, {GATED, PRIOR_DOMINATED}
        return agreed[0], agreed[1], new_ref, 0.0

    def _match_centred(self, scan: RadarScan, x: np.ndarray, twist, interval_s: float, ref_ts: int):
        """(pose in the radar's frame, cov, new reference, its turn) with the new sweep drawn turned
        by the predicted yaw, or None where the graph's output is not finite. A turn beyond
        `MAX_TURN_RAD` re-draws the new reference in its own frame (a second graph call)."""
        pred = self._prior.predict(interval_s, self._lead_s(ref_ts))
        a_ref = self._ref_turn
        a_new = next_turn(a_ref, None if pred is None else float(pred[0][2]))
        drawn = x if a_new == 0.0 else self._sweep_input(scan, SweepMotion(twist=twist, frame_pose=(0.0, 0.0, a_new)))
        out = self._run_pair(drawn)
        if out is None:
            return None
        residual, residual_cov, new_ref = out
        pose, cov = uncentre(residual, residual_cov, a_ref, a_new)
        if abs(a_new) > MAX_TURN_RAD:
            new_ref, a_new = self._run_first(x), 0.0
            if not np.all(np.isfinite(new_ref)):
                return None
        return pose, cov, new_ref, a_new

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
            self._recent_motion.append((np.asarray(rel, dtype=np.float64), dt_s))
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
