"""Pipelined odometry over recordings: the next sweeps are read while the graph runs.

`iter_estimates` steps a `RadarOdometer` through a recording folder (or any iterable of sweep
files or `RadarScan` objects) and yields one ``(index, timestamp_us, estimate)`` per sweep. With
``prefetch`` ≥ 1 a worker thread reads the next sweeps ahead — PNG decode, parse into a
`RadarScan` and `RadarOdometer.prepare` (degeneracy test, polar → Cartesian resampling) — into
a queue of that many sweeps, while the calling thread runs the graph (`RadarOdometer.step`).
``cv2.imdecode`` and onnxruntime release the GIL, so the two overlap; the estimates are exactly
those of the unpipelined loop (``prefetch=0``: everything on the calling thread).

    from radar_odom import RadarOdometer, pretrained
    from radar_odom.odometry.pipeline import iter_estimates

    odo = RadarOdometer(pretrained("cart-0.4"))
    with iter_estimates("seq", odo, prefetch=2) as sweeps:
        for index, timestamp_us, est in sweeps:     # est is None for the first sweep
            ...
    print(sweeps.skipped)                            # sweeps that could not be used
    print(sweeps.throughput().format())              # sweeps/s and the two stages' medians

`throughput` is the measuring behind ``radar-odom run``'s last line: a pure function of the
run's wall time and the per-sweep times of the two stages.
"""
from __future__ import annotations

import math
import queue
import statistics
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, ScanFormatError, StreamError

ON_ERROR = ("skip", "stop", "raise")
DEFAULT_PREFETCH = 2
# a sweep whose first-azimuth time is further than this from its file name's time has a corrupt
# header (names are the first (Oxford, RADIATE), middle (Boreas) or last (MulRan) azimuth's time)
NAME_TIME_TOLERANCE_S = 1.0
WORKER_NAME = "radar-odom-prefetch"
_JOIN_TIMEOUT_S = 5.0  # a worker stuck in a read is a daemon: it never holds up the exit
_POLL_S = 0.05  # longest the consumer waits on the queue before it lets Ctrl-C through


# ------------------------------------------------------------------------------ measuring
@dataclass(frozen=True)
class Throughput:
    """How fast a run went, and how close to the slower stage's pace (`throughput`)."""

    sweeps: int
    wall_s: float
    wall_per_sweep_s: float
    sweeps_per_s: float
    load_median_s: float  # decode + parse + prepare, per sweep
    step_median_s: float  # RadarOdometer.step (the graph), per sweep
    bound_s: float  # max(load_median_s, step_median_s): the best a two-stage pipeline can do
    ratio: float  # wall_per_sweep_s / bound_s (1.0 = perfect overlap; ~ (load + step) / bound serial)

    def format(self) -> str:
        """One line, e.g. for the end of ``radar-odom run``."""
        return (f"{self.sweeps} sweeps in {self.wall_s:.2f} s: {1e3 * self.wall_per_sweep_s:.1f} ms per sweep, "
                f"{self.sweeps_per_s:.2f} sweeps/s; medians: read (decode+parse+prepare) "
                f"{1e3 * self.load_median_s:.1f} ms, "
                f"step {1e3 * self.step_median_s:.1f} ms; wall / max(stages) = {self.ratio:.2f}")

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def throughput(wall_s: float, load_s, step_s, sweeps: int | None = None) -> Throughput:
    """Sweeps/s of a run and its ratio to the slower stage (pure: no clock, no I/O).

    Args:
        wall_s: wall time of the whole loop (s).
        load_s: per-sweep times (s) of the reading stage (decode + parse + prepare).
        step_s: per-sweep times (s) of the stepping stage (`RadarOdometer.step`).
        sweeps: sweeps the loop went through (default: ``len(load_s)``).

    The stage times are summarised by their medians (robust to a noisy machine); the wall time
    per sweep is the mean (it is what a recording costs). ``ratio`` = wall per sweep /
    max(median load, median step): ≈ 1 when the stages overlap perfectly, ≈ their sum over the
    larger when they run one after the other. NaN where a stage has no sample.
    """
    load_s, step_s = list(load_s), list(step_s)
    n = len(load_s) if sweeps is None else int(sweeps)
    load_med, step_med = _median(load_s), _median(step_s)
    per = wall_s / n if n > 0 else math.nan
    bound = max(load_med, step_med) if load_s and step_s else math.nan
    return Throughput(
        sweeps=n, wall_s=float(wall_s), wall_per_sweep_s=per,
        sweeps_per_s=n / wall_s if n > 0 and wall_s > 0 else math.nan,
        load_median_s=load_med, step_median_s=step_med, bound_s=bound,
        ratio=per / bound if bound > 0 else math.nan,
    )


def _median(values: list) -> float:
    return float(statistics.median(values)) if values else math.nan


# ------------------------------------------------------------------------------ prefetching
class _Failure:
    def __init__(self, exc: BaseException):
        self.exc = exc


_DONE = object()


def prefetched(items, load, depth: int):
    """Yield ``(index, item, value, error, seconds)`` for each item, in order.

    ``value = load(item)`` (``error`` None), or ``error`` the `Exception` it raised (``value``
    None); ``seconds`` the time ``load`` took. ``depth`` ≥ 1: a daemon worker thread runs the
    loads up to ``depth`` items ahead; 0: each runs here when its turn comes. An exception from
    iterating ``items`` itself is raised here, in its turn. Closing the generator (``close()``,
    an exception in the consumer, garbage collection) stops the worker: it finishes the load in
    hand, sees the stop flag and exits; the generator waits for it (at most a few seconds).
    """
    if depth <= 0:
        for i, item in enumerate(items):
            t = time.perf_counter()
            try:
                value, error = load(item), None
            except Exception as exc:  # handed to the consumer, in order
                value, error = None, exc
            yield i, item, value, error, time.perf_counter() - t
        return
    q: queue.Queue = queue.Queue(maxsize=int(depth))
    stop = threading.Event()

    def put(msg) -> bool:
        while not stop.is_set():
            try:
                q.put(msg, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for i, item in enumerate(items):
                if stop.is_set():
                    return
                t = time.perf_counter()
                try:
                    value, error = load(item), None
                except Exception as exc:
                    value, error = None, exc
                if not put((i, item, value, error, time.perf_counter() - t)):
                    return
        except BaseException as exc:  # the iterable itself failed: the consumer raises it
            put(_Failure(exc))
            return
        put(_DONE)

    worker = threading.Thread(target=work, name=WORKER_NAME, daemon=True)
    worker.start()
    try:
        while True:
            try:
                # a bounded wait: Python delivers Ctrl-C to the main thread between bytecodes, so a
                # wait with no timeout would hold it until the worker's next item arrived
                msg = q.get(timeout=_POLL_S)
            except queue.Empty:
                continue
            if msg is _DONE:
                return
            if isinstance(msg, _Failure):
                raise msg.exc
            yield msg
    finally:
        stop.set()
        worker.join(_JOIN_TIMEOUT_S)


# ------------------------------------------------------------------------------ the iterator
def _sources(source, load_kwargs: dict):
    """(items, load, describe): ``describe(item) -> (path or None, file-name time µs or None)``."""
    import numpy as np

    from ..io import Sequence, load_scan, read_sequence
    from ..io._layout import name_timestamp, to_microseconds
    from ..scan import RadarScan

    if isinstance(source, (str, Path)) and not Path(source).is_file():
        source = read_sequence(source, **load_kwargs)  # a folder (SequenceError when there is none)
    if isinstance(source, Sequence):
        seq = source
        return (range(len(seq)), seq.scan,
                lambda i: (seq.paths[i], int(seq.timestamps_us[i])))
    if isinstance(source, (str, Path, RadarScan)):
        source = [source]

    def load(item):
        if isinstance(item, RadarScan):
            return item
        if isinstance(item, (str, Path)):
            return load_scan(item, **load_kwargs)
        raise TypeError(f"iter_estimates takes sweep files or RadarScans, got {type(item).__name__}")

    def describe(item):
        if isinstance(item, (str, Path)):
            stamp = name_timestamp(Path(item))
            return item, (None if stamp is None else int(to_microseconds(np.array([stamp]))[0]))
        return getattr(item, "source", None), None

    return iter(source), load, describe


class EstimateStream:
    """What `iter_estimates` returns: iterate it for ``(index, timestamp_us, estimate)``.

    ``index``: the sweep's position in the source; ``timestamp_us``: its time in the trajectory
    (the first azimuth's; a skipped sweep: its file-name time shifted like the sweep before it);
    ``estimate``: its `Estimate`, None for the first sweep of a stream. After (or during) the
    loop: ``skipped`` (dicts: index, path, reason, message, timestamp_us — ``""`` for a sweep left
    out of the trajectory), ``load_seconds`` / ``step_seconds`` (per sweep, the two stages),
    ``index`` (the sweep in hand, e.g. the one an error stopped at), ``wall_s`` and
    `throughput`. A context manager: leaving the ``with`` block (or `close`) stops the worker.
    """

    def __init__(self, source, odometer, prefetch: int, on_error: str, load_kwargs: dict):
        if on_error not in ON_ERROR:
            raise ConfigError(f"on_error must be one of {ON_ERROR}, got {on_error!r}")
        if isinstance(prefetch, bool) or not isinstance(prefetch, int) or prefetch < 0:
            raise ConfigError(f"prefetch must be an integer ≥ 0 (0: no worker thread), got {prefetch!r}")
        self.odometer = odometer
        self.prefetch = prefetch
        self.on_error = on_error
        self.skipped: list[dict] = []
        self.load_seconds: list[float] = []
        self.step_seconds: list[float] = []
        self.index = -1
        self.count = 0  # sweeps taken from the source so far
        self.wall_s = 0.0
        items, read, self._describe = _sources(source, load_kwargs)
        self.length = len(items) if isinstance(items, range) else None
        odo = odometer

        def load(item):
            return odo.prepare(read(item))

        self._loads = prefetched(items, load, prefetch)
        self._iter = self._run()

    def __iter__(self):
        return self._iter

    def __next__(self):
        return next(self._iter)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        """Stop reading ahead (the worker thread ends); idempotent."""
        self._iter.close()
        self._loads.close()

    def throughput(self) -> Throughput:
        """`throughput` of the sweeps so far."""
        return throughput(self.wall_s, self.load_seconds, self.step_seconds, sweeps=self.count)

    def _run(self):
        odo = self.odometer
        name_offset_us = 0  # first-azimuth time − file-name time of the last sweep read
        t0 = time.perf_counter()
        try:
            for i, item, prepared, error, load_s in self._loads:
                self.index, self.count = i, i + 1
                self.load_seconds.append(load_s)
                path, name_us = self._describe(item)
                problem = None
                if error is not None:
                    if not isinstance(error, ScanFormatError):
                        raise error
                    problem = ("unreadable", error)
                else:
                    scan = prepared.scan
                    t = time.perf_counter()
                    try:
                        est = odo.step(prepared)
                    except StreamError as exc:
                        off_s = math.inf if name_us is None else abs(scan.timestamp_us - name_us) * 1e-6
                        stamps = odo.trajectory.timestamps_us
                        stale = len(stamps) > 0 and scan.timestamp_us <= int(stamps[-1])
                        if stale and self.on_error == "skip" and (name_us is None or off_s <= NAME_TIME_TOLERANCE_S):
                            # a duplicate or stale stamp (a bag's re-sent message): that sweep, not the stream
                            problem = ("stale_timestamp", ScanFormatError(
                                f"{path}: timestamp {scan.timestamp_us} µs is not after the previous sweep's "
                                f"{int(stamps[-1])} µs (a duplicate or stale stamp)"))
                        elif name_us is None or off_s <= NAME_TIME_TOLERANCE_S or self.on_error == "raise":
                            # the stream itself is broken (a gap beyond max_gap_s): not one sweep's fault
                            raise
                        else:
                            problem = ("bad_timestamp", ScanFormatError(
                                f"{path}: first azimuth time {scan.timestamp_us} µs is {off_s:.3g} s from the file "
                                f"name's time ({exc}); the sweep's header is corrupt"))
                    else:
                        self.step_seconds.append(time.perf_counter() - t)
                        if name_us is not None:
                            name_offset_us = scan.timestamp_us - name_us
                        self.wall_s = time.perf_counter() - t0
                        # the trajectory's time: the sweep's stamp as given
                        yield i, (scan.timestamp_us if est is None else est.timestamp_us), est
                        continue
                reason, exc = problem
                if self.on_error != "skip":
                    raise exc
                entry = {"index": i, "path": str(path), "reason": reason, "message": str(exc), "timestamp_us": ""}
                if name_us is None:
                    entry["message"] += " (left out of the trajectory: its file name holds no timestamp)"
                    self.skipped.append(entry)
                    continue
                ts = name_us + name_offset_us
                try:
                    est = odo.skip(ts, reason, source=str(path))
                except StreamError as stream_exc:  # not even its file name's time fits: leave it out
                    entry["message"] += f" (left out of the trajectory: {stream_exc})"
                    self.skipped.append(entry)
                    continue
                entry["timestamp_us"] = ts
                self.skipped.append(entry)
                self.wall_s = time.perf_counter() - t0
                yield i, ts, est
            self.index = self.count
        finally:
            self.wall_s = time.perf_counter() - t0
            self._loads.close()


def iter_estimates(source, odometer, *, prefetch: int = DEFAULT_PREFETCH, on_error: str = "skip",
                   **load_kwargs) -> EstimateStream:
    """Step ``odometer`` through ``source``, reading ahead on a worker thread; yields per sweep.

    Args:
        source: a recording folder (as `read_sequence` opens it), a `Sequence`, or any iterable
            of sweep files (paths) and/or `RadarScan` objects, in time order.
        odometer: the `RadarOdometer` to step (its stream goes on from where it is; call its
            ``reset()`` first for a new trajectory).
        prefetch: sweeps read ahead by the worker thread (decode + parse +
            `RadarOdometer.prepare`); 0 reads each on the calling thread when its turn comes.
            The estimates are the same either way.
        on_error: a sweep that cannot be used — unreadable (`ScanFormatError`), or whose first
            azimuth's time disagrees with its file name's by more than ``NAME_TIME_TOLERANCE_S``
            and breaks the time order — ``"skip"`` (default): recorded with
            `RadarOdometer.skip` at its file-name time (yielded, flagged degenerate, listed in
            ``skipped``; left out when even that time does not fit); ``"stop"``: raise its
            `ScanFormatError` (the stream's ``index`` says which sweep); ``"raise"``: as
            ``"stop"``, and a timestamp error is raised as the odometer's `StreamError`.
        **load_kwargs: passed to `read_sequence` / `load_scan` (e.g. ``range_resolution_m``).

    Returns an `EstimateStream`: iterate it for ``(index, timestamp_us, estimate)``; it holds
    ``skipped`` and the stage timings (`EstimateStream.throughput`). Errors that are not one
    sweep's fault (a gap beyond ``max_gap_s``: `StreamError`; `ModelMismatchError`; anything
    else the reading raised) are raised in their turn. Use it as a context manager (or call
    ``close()``) so that leaving the loop early stops the worker at once.

    Example::

        odo = RadarOdometer(pretrained("cart-0.4"))
        with iter_estimates("oxford/2019-01-10-11-46-21", odo) as sweeps:
            for i, t_us, est in sweeps:
                if est is not None:
                    print(i, t_us, est.pose)
        print(sweeps.throughput().format())
    """
    return EstimateStream(source, odometer, prefetch, on_error, load_kwargs)
