"""Odometry over a recorded sequence: estimates, trajectory files, a plot and the KITTI metric.

`run_sequence` is what ``radar-odom run SEQ --model M`` does; `demo` reuses it on a simulated
drive. Outputs in ``out_dir``:

- ``trajectory.tum`` / ``trajectory.kitti``: absolute poses of every sweep (first = identity).
- ``estimates.csv``: one row per step: timestamps of the sweep and its predecessor (µs, the
  Oxford file names), the relative pose (x, y, yaw; Oxford convention), the upper triangle of
  its covariance, the flags ("degenerate", "bridged", "prior_dominated", "gated", ...), and the
  raw match before the motion prior (``meas_x_m``, ``meas_y_m``, ``meas_yaw_rad``; equal to the
  pose when the prior is off).
- ``trajectory.png``: estimate vs ground truth (when there is one), drawn as a map from above.
  Frames are x forward, y right, z down, so the plot shows (x, −y) and −yaw (z up).
- ``ground_truth.tum`` / ``ground_truth.kitti`` (when the recording has ground truth): the same
  sweeps' ground-truth poses in the same frame, so ``evo_ape tum ground_truth.tum
  trajectory.tum`` (or ``evo_rpe kitti ...``) compares them directly. Where a pair lacks ground
  truth the chained poses after it are unknown: the TUM file then holds the poses up to the first
  missing pair, and the KITTI file (which has no timestamps) is not written.
- ``skipped.csv`` (only when a sweep was skipped): index, file, reason and message of each.
- ``partial.txt`` (only when the run stopped before the end: ``on_error="stop"``, a gap beyond ``max_gap_s``, or
  an interrupt): which sweeps the outputs hold and why the run stopped. Written first, so that an output folder
  of a stopped run always says so; no metrics and no ground truth are written beside it.

A run removes these files from ``out_dir`` where it did not write them this time (an earlier run's
``skipped.csv`` or ground truth in the same folder), and nothing else there (`remove_stale_outputs`).

Pace: the next sweeps are decoded, parsed and prepared (`RadarOdometer.prepare`) on a worker
thread while the graph runs on the calling one (``prefetch`` sweeps ahead; 0: one after the
other); the outputs are the same either way. ``RunResult.throughput`` holds the sweeps/s and
the two stages' medians (`radar_odom.odometry.pipeline.throughput`); the loop itself is
`radar_odom.odometry.pipeline.iter_estimates`, the iterator API for library users.

Bad sweeps (``on_error``): a sweep that cannot be read (`ScanFormatError`), or whose own
timestamp is garbage (its first azimuth's time disagrees with its file name by more than
``NAME_TIME_TOLERANCE_S`` and breaks the time order), is *skipped* by default: reported in
`RunResult.skipped`, given a prior-only pose flagged ``degenerate`` + ``unreadable`` /
``bad_timestamp`` (`RadarOdometer.skip`), the next sweep bridged across it, every output still
written. ``on_error="stop"`` writes the outputs for the sweeps before it and raises `RunAborted`.
Interrupted (Ctrl-C's `KeyboardInterrupt`, or what a caller raises for SIGTERM: `radar-odom run` raises one) during
the odometry, the run writes the outputs so far in the same way and raises `RunInterrupted` (a `KeyboardInterrupt`).
Errors that are not one sweep's fault always stop the run: a time gap beyond ``max_gap_s``
(`RunAborted`, after writing the outputs so far) and a model that does not fit the radar
(`ModelMismatchError`).
"""
from __future__ import annotations

import csv
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._progress import progress
from ..errors import (
    ConfigError,
    OutputError,
    RadarOdomError,
    RunAborted,
    RunInterrupted,
    ScanFormatError,
    SequenceError,
    StreamError,
)
from ..evaluation.plot import plot_trajectory
from ..evaluation.reference import gnss_reference
from ..evaluation.report import evaluate
from ..io.recording import open_recording  # noqa: F401  (re-exported: its home is radar_odom.io.recording)
from ..odometry.estimate import Trajectory
from ..odometry.odometer import Estimate, RadarOdometer
from ..odometry.pipeline import DEFAULT_PREFETCH, NAME_TIME_TOLERANCE_S, Throughput, iter_estimates, throughput  # noqa: F401

ESTIMATE_COLUMNS = (
    "timestamp_us", "prev_timestamp_us", "x_m", "y_m", "yaw_rad",
    "cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw", "flags",
    "meas_x_m", "meas_y_m", "meas_yaw_rad",
)
ON_ERROR = ("skip", "stop")
# every file a run writes in out_dir, by name: those this run did not write are removed from there (a
# skipped.csv or ground_truth.tum of an earlier run in the same folder read as this run's); nothing else is
PARTIAL_FILE = "partial.txt"  # beside the outputs of a run that stopped before the end: which sweeps they hold, why
OUTPUT_FILES = ("trajectory.tum", "trajectory.kitti", "estimates.csv", "trajectory.png", "skipped.csv",
                "ground_truth.tum", "ground_truth.kitti", PARTIAL_FILE)


@dataclass
class RunResult:
    """What `run_sequence` produced."""

    poses: np.ndarray  # float64[N, 3, 3] estimated absolute poses
    timestamps_us: np.ndarray  # int64[N]
    estimates: list  # N − 1 `Estimate`s
    gt_poses: np.ndarray | None  # float64[N, 3, 3] ground truth, first = identity, or None
    metrics: dict | None = None  # KITTI metrics, or None
    step_errors: dict | None = None  # mean per-step relative errors when KITTI has no segment
    files: dict = field(default_factory=dict)
    seconds_per_step: float = float("nan")
    skipped: list = field(default_factory=list)  # dicts: index, path, reason, message
    throughput: Throughput | None = None  # the pace: sweeps/s, stage medians (`pipeline.throughput`)
    reference: dict | None = None  # GNSS/INS reference: clock_offset_s, heading_offset_deg, how each was found
    reference_note: str = ""  # one line saying which reference the metrics use (GNSS/INS: its calibration)
    time_base: object = None  # the recording's `TimeBase` with the sweep times the match decided, or None
    problems: list = field(default_factory=list)  # stages after the odometry that failed (plot, bag, metrics): why

    @property
    def complete(self) -> bool:
        """True when no sweep was skipped."""
        return not self.skipped

    @property
    def num_degenerate(self) -> int:
        return sum(e.degenerate for e in self.estimates)


def write_estimates_csv(path, estimates: list[Estimate], prev_timestamps_us) -> Path:
    """``estimates.csv`` (see the module docstring for the columns)."""
    path = Path(path)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(ESTIMATE_COLUMNS)
        for est, prev in zip(estimates, prev_timestamps_us):
            c = est.covariance
            w.writerow([
                est.timestamp_us, int(prev), *(f"{v:.9g}" for v in est.pose),
                *(f"{v:.9g}" for v in (c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2])),
                "|".join(sorted(est.flags)), *(f"{v:.9g}" for v in est.measurement),
            ])
    return path


def read_estimates_csv(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[frozenset]]:
    """(timestamps_us int64[M], poses float64[M, 3], covariances float64[M, 3, 3], flags)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    ts = np.array([int(r["timestamp_us"]) for r in rows], dtype=np.int64)
    poses = np.array([[float(r[k]) for k in ("x_m", "y_m", "yaw_rad")] for r in rows]).reshape(-1, 3)
    covs = np.zeros((len(rows), 3, 3))
    for i, r in enumerate(rows):
        for (a, b), k in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)), ESTIMATE_COLUMNS[5:11]):
            covs[i, a, b] = covs[i, b, a] = float(r[k])
    flags = [frozenset(x for x in r["flags"].split("|") if x) for r in rows]
    return ts, poses, covs, flags


def prepare_output_dir(out_dir) -> Path:
    """Create ``out_dir`` (and parents); `OutputError` if it is a file or cannot be created."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder; give -o a folder (new or existing)")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out_dir}: cannot create the output folder ({exc.strerror or exc})") from None
    return out_dir


@contextmanager
def new_folder_removed_on_error(out_dir):
    """`prepare_output_dir`, yielding the folder; if the body raises and the folder was made here and is still
    empty, it is removed again: a refused or failed run leaves no empty output folder behind."""
    out_dir = Path(out_dir)
    made = not out_dir.exists()
    out_dir = prepare_output_dir(out_dir)
    try:
        yield out_dir
    except BaseException:
        if made:
            try:
                out_dir.rmdir()  # only an empty folder: whatever was written stays
            except OSError:
                pass
        raise


def earlier_outputs(out_dir) -> list[str]:
    """The names of `OUTPUT_FILES` already in ``out_dir`` (an earlier run's), sorted; [] for a new folder."""
    out_dir = Path(out_dir)
    return sorted(n for n in OUTPUT_FILES if (out_dir / n).is_file()) if out_dir.is_dir() else []


def write_skipped_csv(path, skipped: list[dict]) -> Path:
    """``skipped.csv``: index, timestamp (µs, as recorded in the trajectory), file, reason, message."""
    path = Path(path)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("index", "timestamp_us", "path", "reason", "message"))
        for s in skipped:
            w.writerow((s["index"], s.get("timestamp_us", ""), s["path"], s["reason"], s["message"]))
    return path


def run_sequence(seq_dir, model, out_dir, *, threads=None, max_gap_s: float | None = None, show_progress=True,
                 plot=True, title=None, motion_prior=True, on_error: str = "skip",
                 prefetch: int = DEFAULT_PREFETCH, deskew: bool | None = None, centre_yaw: bool | None = None,
                 gt_time_offset: float | None = None, gt_heading_offset_deg: float | None = None,
                 topic: str | None = None, bag_geometry: dict | None = None, bag_out=None,
                 repair_stamps: bool = True, plain: bool = False) -> RunResult:
    """Run ``model`` (path or `RadarOdometer`) over the recording ``seq_dir``; write outputs.

    ``motion_prior`` (True, False or a `MotionPriorConfig`) is passed to the `RadarOdometer`
    built from a path; an odometer given as ``model`` keeps its own setting. ``on_error``:
    ``"skip"`` (default) or ``"stop"`` for a sweep that cannot be used (module docstring).
    ``prefetch``: sweeps decoded ahead on a worker thread while the graph runs
    (`radar_odom.odometry.pipeline.iter_estimates`; 0: no worker). The outputs do not depend on it;
    ``RunResult.throughput`` reports the pace (`radar_odom.odometry.pipeline.throughput`). ``max_gap_s``:
    None crosses every gap (`RadarOdometer`); ``deskew``, ``centre_yaw``: None takes the odometer's default.
    ``plain``: plain matching (`OdometerConfig.plain`, `radar-odom run --plain`), the stamps as recorded
    (``repair_stamps`` False) and ``motion_prior`` ignored.
    A GNSS/INS reference (RADIATE ``GPS_IMU_Twist/``) is aligned to the radar first:
    ``gt_time_offset`` (s; the reference for radar time t is the sample at t + offset) and
    ``gt_heading_offset_deg`` (the INS heading minus the direction of travel, counter-clockwise)
    are estimated from the data when None (`radar_odom.io.gnss_ins`) and reported in
    ``RunResult.reference``.

    ROS bags (``seq_dir`` a ``.bag`` / ``.mcap`` / ROS 2 bag folder, the ``ros`` extra): the radar
    ``topic`` (None: the bag's only radar topic) is read as `radar_odom.io.bag.BagSequence`
    with ``bag_geometry`` (`radar_odom.ros.msgs.PolarImageGeometry` fields). ``bag_out``: a path
    for a ROS 2 MCAP bag of ``nav_msgs/Odometry`` and TF (`radar_odom.io.bag_out`), written with the
    other outputs (``RunResult.files["bag"]``). ``repair_stamps``: False keeps the sweep stamps as recorded
    (RADIATE, bags; `radar_odom.io.recording.open_recording`).

    Raises `OutputError` when ``out_dir`` cannot be a folder, `RunAborted` (``on_error="stop"``,
    after writing the outputs so far, marked partial), `RunInterrupted` (a `KeyboardInterrupt` during the
    odometry, after the same), and the typed errors of `read_sequence` / `RadarOdometer`.
    """
    if on_error not in ON_ERROR:
        raise ConfigError(f"on_error must be one of {ON_ERROR}, got {on_error!r}")
    # what can be refused is refused before the output folder is made: a refusal leaves no empty folder behind
    seq = open_recording(seq_dir, topic, bag_geometry, repair_stamps=repair_stamps and not plain)
    if bag_out is not None:  # what can be checked before the run, not after it
        check_bag_out(bag_out)
    with new_folder_removed_on_error(out_dir) as out_dir:
        return _run(seq, seq_dir, model, out_dir, threads=threads, max_gap_s=max_gap_s, show_progress=show_progress,
                    plot=plot, title=title, motion_prior=motion_prior, on_error=on_error, prefetch=prefetch,
                    deskew=deskew, centre_yaw=centre_yaw, reference_offsets=(gt_time_offset, gt_heading_offset_deg),
                    bag_out=bag_out, plain=plain)


def _run(seq, seq_dir, model, out_dir, *, threads, max_gap_s, show_progress, plot, title, motion_prior, on_error,
         prefetch, deskew, centre_yaw, reference_offsets, bag_out, plain=False) -> RunResult:
    extra = {k: bool(v) for k, v in (("deskew", deskew), ("centre_yaw", centre_yaw)) if v is not None}
    if plain:
        extra = {**extra, "config": "plain"}
    else:
        extra["motion_prior"] = motion_prior
    odo = model if isinstance(model, RadarOdometer) else RadarOdometer(
        model, threads=threads, max_gap_s=max_gap_s, **extra)
    odo.reset()
    estimates: list[Estimate] = []
    prev_ts: list[int] = []
    last_ts = None
    stream = iter_estimates(seq, odo, prefetch=prefetch, on_error=on_error)

    def finish(complete: bool, sweeps: int | None = None, why: str = "") -> RunResult:
        stream.close()
        result = _write_outputs(odo, seq, seq_dir, out_dir, estimates, prev_ts, stream.skipped,
                                stream.throughput(), plot, title, complete,
                                reference_offsets=reference_offsets, sweeps=sweeps, why=why)
        if bag_out is not None:
            try:
                result.files["bag"] = _write_bag(bag_out, seq, result)
            except (RadarOdomError, OSError) as exc:  # the estimates are written: say why, keep them
                result.problems.append(f"--bag-out {bag_out} not written: {exc}")
        return result

    def aborted(exc, why: str = "") -> RunAborted:
        where = f"stopped at sweep {stream.index} of {len(seq)}{why}"
        result = finish(complete=False, why=f"{where}: {exc}")
        return RunAborted(
            f"{exc} [{where}; the outputs for the {len(result.timestamps_us)} sweeps before it are in {out_dir}, "
            f"marked partial ({PARTIAL_FILE})]", result, exc)

    def interrupted(exc: BaseException, upto: tuple) -> RunInterrupted:
        # Python raises the interrupt between any two bytecodes, in a step or in this loop's bookkeeping: the
        # outputs are those of the sweeps ``upto`` records as done, whatever the odometer went on to append
        handled, kept, poses = upto
        del estimates[kept:], prev_ts[kept:]
        where = f"interrupted at sweep {handled} of {len(seq)}"
        result = finish(complete=False, sweeps=poses, why=where)
        return RunInterrupted(
            f"{where}: the outputs for the {len(result.timestamps_us)} sweeps before it are written to {out_dir}, "
            f"marked partial ({PARTIAL_FILE}; no metrics or ground truth)", result, exc)

    done = 0
    upto = (0, 0, 0)  # (sweeps of the recording handled, estimates kept, trajectory poses): one assignment a sweep
    bar = progress(total=len(seq), desc=f"odometry {Path(seq_dir).name}", unit="sweep", disable=not show_progress)
    try:
        with stream:
            try:
                for i, ts, est in stream:
                    if est is not None:
                        estimates.append(est)
                        prev_ts.append(last_ts)
                    last_ts = ts
                    upto = (i + 1, len(estimates), upto[2] + 1)  # every sweep yielded holds one trajectory pose
                    bar.update(stream.count - done)
                    done = stream.count
            except StreamError as exc:
                # the stream itself is broken there (a gap beyond max_gap_s): not one sweep's
                # fault, so the run stops, with the outputs so far written
                raise aborted(exc) from None
            except ScanFormatError as exc:  # on_error="stop": the sweep that could not be used
                raise aborted(exc, " (on_error='stop')") from None
        bar.update(len(seq) - done)
    except KeyboardInterrupt as exc:  # Ctrl-C (or the command line's SIGTERM): the work so far is kept
        bar.close()
        raise interrupted(exc, upto) from None
    finally:
        bar.close()
    if len(seq) and len(stream.skipped) >= len(seq):
        # not one sweep could be used: an all-identity trajectory would look like a result
        first = stream.skipped[0]
        raise SequenceError(f"{seq_dir}: none of its {len(seq)} sweeps could be used (the first, {first['path']}: "
                            f"{first['reason']}: {first['message']}); nothing to estimate")
    try:
        return finish(complete=True)
    except KeyboardInterrupt as exc:  # the odometry is done, its files perhaps not all written: said, and marked
        where = f"interrupted while writing the outputs of all {len(seq)} sweeps"
        _mark_partial(out_dir, where, None, len(seq))
        raise RunInterrupted(f"{where}: those in {out_dir} may be incomplete, marked partial ({PARTIAL_FILE})",
                             None, exc) from None


def check_bag_out(path) -> None:
    """`OutputError` (or `MissingExtraError`) now for a ``--bag-out`` path that could not be written
    after the odometry: one that exists, a folder that is missing or read-only, no rosbags."""
    import os

    from ..io.bag_out import _rosbags_writer

    path = Path(path)
    if path.exists():
        raise OutputError(f"{path}: exists; --bag-out writes a new ROS 2 bag, give a new path")
    parent = path.resolve().parent
    if not parent.is_dir():
        raise OutputError(f"{path}: folder {parent} does not exist; create it or give another --bag-out path")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{path}: folder {parent} is not writable; give another --bag-out path")
    _rosbags_writer()  # MissingExtraError with the pip line, before the run


def _write_bag(path, seq, result: RunResult) -> Path:
    """The run's odometry as a ROS 2 bag, stamped with the input messages' stamps where known."""
    from ..io.bag_out import write_odometry_bag

    by_first_us = dict(zip(getattr(seq, "timestamps_us", ()).tolist(), getattr(seq, "stamps_ns", ())))
    stamps = [int(by_first_us.get(int(t), int(t) * 1000)) for t in result.timestamps_us]
    return write_odometry_bag(path, result.timestamps_us, result.poses, result.estimates, stamps)


def _mark_partial(out_dir, why: str, sweeps: int | None, total: int) -> Path | None:
    """`PARTIAL_FILE` in ``out_dir``: the outputs there are of a run that stopped (``why``), holding the first
    ``sweeps`` of the recording's ``total`` (None: not known). None where it cannot be written (the outputs are
    the work: a marker that fails costs nothing else)."""
    held = "" if sweeps is None else f"These outputs hold the first {sweeps} of the recording's {total} sweeps. "
    text = (f"partial: {why}.\n{held}No metrics and no ground truth were written for them; run the recording "
            "again for the whole of it (radar-odom run: --overwrite replaces these).\n")
    try:
        path = Path(out_dir) / PARTIAL_FILE
        path.write_text(text)
        return path
    except OSError:
        return None


def _write_outputs(odo, seq, seq_dir, out_dir, estimates, prev_ts, skipped, pace: Throughput, plot, title,
                   complete: bool, reference_offsets=(None, None), sweeps: int | None = None,
                   why: str = "") -> RunResult:
    from ..evaluation.metrics import covariance_jitter
    from ..evaluation.trajectory import write_kitti, write_tum

    traj = odo.trajectory
    if sweeps is not None and len(traj) > sweeps:  # an interrupted step's pose, its estimate never handed out
        traj = Trajectory(traj.poses[:sweeps], traj.timestamps_us[:sweeps])
    partial = None if complete else _mark_partial(out_dir, why or "the run stopped", len(traj), len(seq))
    result = RunResult(traj.poses, traj.timestamps_us, estimates, None,
                       seconds_per_step=pace.wall_s / max(len(traj), 1), skipped=list(skipped), throughput=pace)
    if partial is not None:
        result.files["partial"] = partial
    # the one time base of the run: the reader's, with the whole periods the match decided (the reference's too)
    result.time_base = getattr(seq, "time_base", None)
    result.files["tum"] = write_tum(out_dir / "trajectory.tum", traj.timestamps_us, traj.poses)
    result.files["kitti"] = write_kitti(out_dir / "trajectory.kitti", traj.poses)
    result.files["estimates"] = write_estimates_csv(out_dir / "estimates.csv", estimates, prev_ts)
    if skipped:
        result.files["skipped"] = write_skipped_csv(out_dir / "skipped.csv", skipped)
    gt = seq.gt_absolute()
    n = len(traj)
    if gt is None and complete and n == len(seq) and n >= 2:
        # the reference is read (a few thousand small files) and aligned only now, after the
        # odometry: whatever is wrong with it costs the metrics, never the estimates written above
        try:
            track = getattr(seq, "reference", None)
            if track is not None:
                # the reader's time base, where it fitted one: the reference at the very times the odometry used
                gt, result.reference, result.reference_note = gnss_reference(
                    track, traj.timestamps_us, traj.poses, *reference_offsets, time_base=result.time_base)
        except (SequenceError, ConfigError) as exc:  # unreadable or cannot be aligned: say so, no metrics
            result.reference_note = f"reference: GNSS/INS present but not used ({exc})"
            gt = None
    if gt is not None and complete and n == len(seq) and len(gt) == n:
        result.gt_poses = gt
        p = odo.info.profile
        try:
            result.metrics, result.step_errors = evaluate(
                gt, traj.poses, estimates, covariance_jitter(p.resolution_m, p.rotation_step_rad),
                gt_relative=seq.gt_relative)
        except (ValueError, ArithmeticError) as exc:  # e.g. a ground truth of 1e308 m: no metrics, say why
            result.problems.append(f"metrics not computed: {type(exc).__name__}: {exc}")
    if gt is not None and complete and n == len(seq) and len(gt) == n:
        # one ground-truth pose per estimated pose, stamped like the estimate so that evo pairs
        # them by time (TUM) or by line (KITTI); unknown past the first pair without ground truth
        known = np.all(np.isfinite(gt.reshape(n, -1)), axis=1)
        upto = n if known.all() else int(np.argmin(known))
        if upto >= 2:  # an empty (or one-pose) file listed as the ground truth would look like a result
            result.files["gt_tum"] = write_tum(out_dir / "ground_truth.tum", traj.timestamps_us[:upto], gt[:upto])
        else:
            result.problems.append("ground_truth.tum not written: the ground truth is unknown from the second sweep on")
        if known.all():
            result.files["gt_kitti"] = write_kitti(out_dir / "ground_truth.kitti", gt)
    if plot:
        try:
            result.files["plot"] = plot_trajectory(
                out_dir / "trajectory.png", traj.poses, result.gt_poses, traj.timestamps_us,
                title or f"{Path(seq_dir).name} — {Path(str(odo.path)).name}",
            )
        except (RadarOdomError, OSError, ValueError) as exc:  # the trajectory files are written already
            result.problems.append(f"plot not drawn: {exc}")
    result.problems.extend(remove_stale_outputs(out_dir, result.files.values()))
    return result


def remove_stale_outputs(out_dir, written) -> list[str]:
    """Remove the files of `OUTPUT_FILES` in ``out_dir`` that are not in ``written`` (an earlier run's), so the
    folder holds this run's outputs only; returns a line per file that could not be removed. Only those names,
    only plain files: whatever else the folder holds is left alone."""
    out_dir = Path(out_dir)
    keep = {Path(p).name for p in written if Path(p).parent == out_dir}
    problems = []
    for name in OUTPUT_FILES:
        path = out_dir / name
        if name in keep or path.is_symlink() or not path.is_file():
            continue
        try:
            path.unlink()
        except OSError as exc:
            problems.append(f"{path}: an earlier run's output, not removed ({exc.strerror or exc}); it is not "
                            "this run's")
    return problems
