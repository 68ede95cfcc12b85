"""Offline batches: many consecutive pairs per graph call, with a sequence-form model file.

    info = match_sequence("cart-0.4-seq.onnx", scans)       # scans: RadarScans in time order
    info.poses          # float64[T − 1, 3]: sweep k + 1 in sweep k's frame (x m, y m, yaw rad)
    info.covariances    # float64[T − 1, 3, 3]

A sequence-form file (``radar-odom export cart-0.4 --form sequence --search fast``) holds the
coarse-to-fine search of the shipped stream models applied to T consecutive sweeps in one call:
each sweep is masked and transformed once, and the T − 1 pairs are searched together, so
onnxruntime runs a few large operators instead of T − 1 small steps. The numbers are those of
the stream form, step by step (tests/test_batch.py), and how much faster that is depends on
the grid (README, "Batched pairs").

This is the graph's own measurement, pair by pair: no motion prior, no bridging of degenerate
sweeps. A degenerate sweep (`radar_odom.odometry.odometer.sweep_problem`), a sweep the model cannot take,
or timestamps that do not increase raise an error naming the sweep; for recordings with faults,
and for the prior, use `RadarOdometer`, which handles them (``radar-odom run``).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._progress import progress as progress_bar
from ..errors import ConfigError, ModelMismatchError, StreamError
from ..onnx_model import OnnxModel
from ..scan import RadarScan
from ..se2 import turn_frame
from .odometer import MIN_COVERAGE, check_sweep_geometry, graph_input, model_region_m, sweep_problem

DEFAULT_BATCH = 16  # pairs per graph call; from 4 on the time per pair stopped falling (README)


@dataclass(frozen=True)
class SequenceMatches:
    """What `match_sequence` returns.

    Attributes:
        poses: float64[T − 1, 3], pose k = sweep k + 1 in sweep k's frame (x m, y m, yaw rad).
        covariances: float64[T − 1, 3, 3] over (x, y, yaw), symmetric.
        timestamps_us: int64[T] the sweeps' timestamps (their index 0..T − 1 for array input).
    """

    poses: np.ndarray
    covariances: np.ndarray
    timestamps_us: np.ndarray


def _model(model, threads) -> OnnxModel:
    m = model if isinstance(model, OnnxModel) else OnnxModel(model, threads)
    if m.info.form != "sequence":
        raise ModelMismatchError(
            f"{m.path.name} is a {m.info.form}-form model; match_sequence needs the sequence form: export "
            f"one with `radar-odom export {m.path.stem} --form sequence --search fast` (or step a "
            "stream-form model with RadarOdometer)"
        )
    return m


def check_array_inputs(x: np.ndarray) -> None:
    """`StreamError` naming the rows of a graph-input array [T, ...] that cannot be matched, as the
    RadarScan path refuses a degenerate sweep: NaN or infinite values, or an image that is one value
    throughout (all zero, say). The graph matches a flat image against anything with full confidence at
    a corner of its search window, so such a row would pass as a match."""
    flat = x.reshape(len(x), -1)
    if flat.shape[1] == 0:
        return
    nonfinite = np.flatnonzero(~np.isfinite(flat).all(axis=1))
    if nonfinite.size:
        raise StreamError(f"sweep array rows {nonfinite[:5].tolist()} hold NaN or infinite values; "
                          "fix or drop those sweeps")
    constant = np.flatnonzero(flat.max(axis=1) == flat.min(axis=1))
    if constant.size:
        more = f" and {constant.size - 5} more" if constant.size > 5 else ""
        raise StreamError(
            f"sweep array rows {constant[:5].tolist()}{more} are degenerate (one value throughout, e.g. row "
            f"{int(constant[0])}: {float(flat[constant[0], 0]):g}: a blank image); match_sequence matches every "
            "consecutive pair — fix or drop those sweeps, or step RadarScans with RadarOdometer (radar-odom run), "
            "which bridges such sweeps")


def sequence_inputs(model: OnnxModel, sweeps, *, min_valid_fraction: float = 0.5,
                    min_coverage: float = MIN_COVERAGE) -> tuple[np.ndarray, np.ndarray]:
    """(graph inputs float32[T, ...], timestamps int64[T]) of ``sweeps``, checked.

    ``sweeps``: RadarScans in time order, or an array of graph inputs [T, *input_shape[1:]]
    (e.g. Cartesian images already made with `polar_to_cartesian`). A degenerate sweep raises
    `StreamError` naming it, in either form (`sweep_problem`; `check_array_inputs`).
    """
    info = model.info
    want = tuple(info.input_shape[1:])
    if isinstance(sweeps, np.ndarray):
        x = sweeps
        if x.ndim != len(want) + 1 or tuple(x.shape[1:]) != want:
            raise ModelMismatchError(
                f"sweep array has shape {list(x.shape)}; model {model.path.name} takes "
                f"[T, {', '.join(map(str, want))}] (T graph inputs along axis 0)"
            )
        check_array_inputs(x)
        x = np.ascontiguousarray(x, dtype=np.float32)
        stamps = np.arange(len(x), dtype=np.int64)
    else:
        scans = list(sweeps)
        lo, hi = model_region_m(info)
        rows, stamps = [], []
        for k, scan in enumerate(scans):
            if not isinstance(scan, RadarScan):
                raise TypeError(f"sweep {k}: match_sequence takes RadarScans or an array, got {type(scan).__name__}")
            if stamps and scan.timestamp_us <= stamps[-1]:
                raise StreamError(f"{scan.source}: timestamp {scan.timestamp_us} µs does not increase (previous "
                                  f"sweep {stamps[-1]} µs); pass the sweeps in time order")
            check_sweep_geometry(scan, info, model.path.name)
            problem = sweep_problem(scan, min_valid_fraction, min_range_m=lo, max_range_m=hi,
                                    min_coverage=min_coverage)
            if problem is not None:
                raise StreamError(f"{scan.source}: degenerate sweep ({problem}); match_sequence matches every "
                                  "consecutive pair — use RadarOdometer (radar-odom run), which bridges such sweeps")
            rows.append(graph_input(scan, info)[0])
            stamps.append(int(scan.timestamp_us))
        x = np.stack(rows) if rows else np.zeros((0, *want), np.float32)
        stamps = np.asarray(stamps, dtype=np.int64)
    if len(x) < 2:
        raise ValueError(f"match_sequence needs at least 2 sweeps, got {len(x)}")
    return x, stamps


def match_sequence(model, sweeps: Sequence[RadarScan] | np.ndarray, *, batch: int = DEFAULT_BATCH,
                   threads: int | None = None, progress: bool = False) -> SequenceMatches:
    """Relative pose and covariance of every consecutive pair of ``sweeps``, ``batch`` pairs per call.

    Args:
        model: path of a sequence-form ``.onnx`` file, or an `OnnxModel` of one.
        sweeps: RadarScans in time order, or graph inputs float[T, ...] (see `sequence_inputs`).
        batch: pairs per graph call (≥ 1); consecutive calls share one sweep.
        threads: onnxruntime intra-op threads when ``model`` is a path.
        progress: show a progress bar over the calls (tqdm, from the ``cli`` extra; none without it).
    Raises `ModelMismatchError` for a model that is not of the sequence form or sweeps it cannot
    take, `StreamError` for timestamps that do not increase or a degenerate sweep, ValueError
    for fewer than two sweeps or non-finite values, `ConfigError` for a bad ``batch``.
    """
    if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
        raise ConfigError(f"batch must be a positive integer (pairs per call), got {batch!r}")
    m = _model(model, threads)
    x, stamps = sequence_inputs(m, sweeps)
    name = m.info.inputs[0]
    starts = range(0, len(x) - 1, int(batch))
    if progress:
        starts = progress_bar(starts, total=len(starts), desc="matching", unit="call")
    poses, covs = [], []
    for c in starts:
        out = m.run({name: x[c: c + int(batch) + 1]})
        poses.append(np.asarray(out["pose"], dtype=np.float64).reshape(-1, 3))
        covs.append(np.asarray(out["covariance"], dtype=np.float64).reshape(-1, 3, 3))
    pose, cov = np.concatenate(poses), np.concatenate(covs)
    bad = np.flatnonzero(~(np.isfinite(pose).all(axis=1) & np.isfinite(cov).reshape(len(cov), -1).all(axis=1)))
    if len(bad):
        raise StreamError(f"the graph gave non-finite poses for pairs {bad[:5].tolist()} (sweeps k, k + 1); "
                          "use RadarOdometer, which replaces such matches by the motion prior")
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    mount = m.info.mount_yaw_rad
    if mount:  # the vehicle's poses, as `RadarOdometer` gives them
        pose, cov = turn_frame(pose, cov, mount)
    return SequenceMatches(pose, cov, stamps)
