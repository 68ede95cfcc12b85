"""Pipelined recordings (issue 14): the worker thread reads ahead, results are those of the plain loop."""
import math
import threading
import time

import numpy as np
import pytest

from radar_odom import RadarOdometer, ScanFormatError, SequenceError, StreamError
from radar_odom.io import load_scan, read_sequence
from radar_odom.odometry.pipeline import WORKER_NAME, iter_estimates, prefetched, throughput
from radar_odom.runs.run_sequence import read_estimates_csv, run_sequence

FRAMES = 8


@pytest.fixture(scope="module")
def model_path(cli_model):
    """The committed untrained raw-scan model of the simulator's default sweeps (no torch needed)."""
    return cli_model


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("sim") / "drive", seed=5, frames=FRAMES, progress=False)


def workers_alive():
    return [t for t in threading.enumerate() if t.name == WORKER_NAME and t.is_alive()]


def assert_same_estimates(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert (x is None) == (y is None)
        if x is not None:
            assert x.timestamp_us == y.timestamp_us and x.flags == y.flags
            np.testing.assert_array_equal(x.pose, y.pose)
            np.testing.assert_array_equal(x.covariance, y.covariance)


def corrupt_copy(drive, dest, index=3):
    import shutil

    shutil.copytree(drive, dest)
    bad = sorted((dest / "radar").glob("*.png"))[index]
    bad.write_bytes(bad.read_bytes()[:200])  # truncated
    return dest, bad


# ---------------------------------------------------------------------------- same results
def test_pipelined_run_gives_the_same_trajectory_as_the_plain_loop(model_path, drive, tmp_path):
    odo = RadarOdometer(model_path)
    plain = []
    for frame in read_sequence(drive):  # what a user without the pipeline writes
        plain.append(odo.step(frame.scan))
    plain_poses = odo.trajectory.poses
    for prefetch in (0, 1, 3):
        result = run_sequence(drive, odo, tmp_path / f"p{prefetch}", show_progress=False, plot=False,
                              prefetch=prefetch)
        assert_same_estimates(result.estimates, plain[1:])
        np.testing.assert_array_equal(result.poses, plain_poses)
        pace = result.throughput
        assert pace.sweeps == FRAMES and len(pace.as_dict()) == 8
        assert pace.sweeps_per_s > 0 and pace.ratio > 0 and pace.load_median_s > 0 and pace.step_median_s > 0
    a = (tmp_path / "p0" / "estimates.csv").read_bytes()
    assert a == (tmp_path / "p3" / "estimates.csv").read_bytes()
    assert not workers_alive()


def test_iter_estimates_takes_folders_sequences_paths_and_scans(model_path, drive):
    odo = RadarOdometer(model_path)
    seq = read_sequence(drive)
    with iter_estimates(drive, odo, prefetch=2) as sweeps:
        reference = list(sweeps)
    assert [i for i, _, _ in reference] == list(range(FRAMES))
    assert [t for _, t, _ in reference] == odo.trajectory.timestamps_us.tolist()
    assert reference[0][2] is None and all(e is not None for _, _, e in reference[1:])
    assert sweeps.skipped == [] and len(sweeps.load_seconds) == len(sweeps.step_seconds) == FRAMES
    assert sweeps.throughput().sweeps == FRAMES and not workers_alive()
    scans = [load_scan(p) for p in seq.paths]
    for source in (seq, list(seq.paths), [str(p) for p in seq.paths], scans, iter(scans)):
        odo.reset()
        got = list(odo.iter_estimates(source, prefetch=1))
        assert [(i, t) for i, t, _ in got] == [(i, t) for i, t, _ in reference]
        assert_same_estimates([e for _, _, e in got], [e for _, _, e in reference])


def test_prepared_sweep_steps_like_the_scan_and_is_tied_to_its_odometer(model_path, drive):
    seq = read_sequence(drive)
    a, b = RadarOdometer(model_path), RadarOdometer(model_path)
    for i in range(3):
        scan = seq.scan(i)
        prepared = b.prepare(scan)
        assert prepared.ready and prepared.problem is None and prepared.input.shape == (1, 64, 64)
        est_b = b.step(prepared)
        est_a = a.step(b.prepare(scan))  # another odometer's: a works from the scan itself
        assert_same_estimates([est_a], [est_b])
    with pytest.raises(TypeError):
        a.prepare(np.zeros((4, 4)))


# ---------------------------------------------------------------------------- errors, in order
def test_a_corrupt_sweep_is_skipped_in_its_turn_like_without_the_pipeline(model_path, drive, tmp_path):
    rec, bad = corrupt_copy(drive, tmp_path / "rec")
    odo = RadarOdometer(model_path)
    results = [run_sequence(rec, odo, tmp_path / f"o{k}", show_progress=False, plot=False, prefetch=k)
               for k in (0, 2)]
    for r in results:
        assert [s["index"] for s in r.skipped] == [3] and r.skipped[0]["path"] == str(bad)
        assert r.skipped[0]["reason"] == "unreadable" and len(r.timestamps_us) == FRAMES
    assert_same_estimates(results[0].estimates, results[1].estimates)
    assert (tmp_path / "o0" / "skipped.csv").read_bytes() == (tmp_path / "o2" / "skipped.csv").read_bytes()
    _, _, _, flags = read_estimates_csv(tmp_path / "o2" / "estimates.csv")
    assert {"degenerate", "unreadable"} <= flags[2] and "bridged" in flags[3]


def test_on_error_stop_raises_at_the_corrupt_sweep_after_the_ones_before(model_path, drive, tmp_path):
    rec, bad = corrupt_copy(drive, tmp_path / "rec")
    odo = RadarOdometer(model_path)
    seen = []
    with pytest.raises(ScanFormatError) as info:
        with iter_estimates(rec, odo, prefetch=3, on_error="stop") as sweeps:
            for i, _, _ in sweeps:
                seen.append(i)
    assert seen == [0, 1, 2] and sweeps.index == 3 and str(bad) in str(info.value)
    assert len(odo.trajectory) == 3 and not workers_alive()


def test_a_gap_in_time_is_the_streams_fault_and_raised_in_turn(model_path, drive):
    odo = RadarOdometer(model_path, max_gap_s=0.1)  # the simulator's sweeps are 0.25 s apart
    with pytest.raises(StreamError, match="max_gap_s"):
        list(iter_estimates(drive, odo, prefetch=2))
    assert not workers_alive()


def test_errors_that_are_not_one_sweeps_fault_propagate(model_path, drive):
    odo = RadarOdometer(model_path)

    def source():
        yield from read_sequence(drive).paths[:2]
        raise RuntimeError("the source broke")

    seen = []
    with pytest.raises(RuntimeError, match="source broke"):
        for i, _, _ in iter_estimates(source(), odo, prefetch=2):
            seen.append(i)
    assert seen == [0, 1] and not workers_alive()
    with pytest.raises(TypeError, match="sweep files or RadarScans"):
        list(iter_estimates([42], odo, prefetch=2))
    with pytest.raises(SequenceError, match="does not exist"):
        iter_estimates(drive / "no-such-recording", odo)
    with pytest.raises(ValueError, match="prefetch"):
        iter_estimates(drive, odo, prefetch=-1)
    with pytest.raises(ValueError, match="on_error"):
        iter_estimates(drive, odo, on_error="ignore")


# ---------------------------------------------------------------------------- the worker stops
def test_ctrl_c_during_a_step_stops_the_worker(model_path, drive, tmp_path, monkeypatch):
    odo = RadarOdometer(model_path)
    real_step, calls = odo.step, []

    def step(scan, odometry=None):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real_step(scan, odometry)

    monkeypatch.setattr(odo, "step", step)
    t = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        run_sequence(drive, odo, tmp_path / "o", show_progress=False, plot=False, prefetch=2)
    assert not workers_alive() and time.perf_counter() - t < 30


def test_leaving_the_loop_early_stops_the_worker(model_path, drive):
    odo = RadarOdometer(model_path)
    with iter_estimates(drive, odo, prefetch=2) as sweeps:
        for i, _, _ in sweeps:
            assert workers_alive()
            if i == 1:
                break
    assert not workers_alive()
    stream = iter_estimates(drive, odo, prefetch=2)  # never iterated: no thread was started
    stream.close()
    assert not workers_alive()


def test_prefetched_keeps_order_hands_errors_over_in_turn_and_stays_bounded():
    loaded = []

    def load(x):
        loaded.append(x)
        time.sleep(0.001 * (x % 3))  # uneven load times
        if x == 4:
            raise ScanFormatError("bad item 4")
        return 10 * x

    for depth in (0, 1, 2, 4):
        loaded.clear()
        got = list(prefetched(range(9), load, depth))
        assert [g[0] for g in got] == list(range(9)) and [g[1] for g in got] == list(range(9))
        assert [g[2] for g in got] == [10 * x if x != 4 else None for x in range(9)]
        assert isinstance(got[4][3], ScanFormatError) and all(g[3] is None for g in got if g[0] != 4)
        assert all(g[4] >= 0 for g in got)
    # bounded: while the consumer holds the first item the worker reads at most depth + 1 more
    loaded.clear()
    gen = prefetched(range(100), load, 2)
    next(gen)
    time.sleep(0.3)
    assert len(loaded) <= 1 + 2 + 1
    gen.close()
    assert not workers_alive()


def test_ctrl_c_while_waiting_for_the_worker_stops_it():
    import _thread
    import signal

    def slow(x):
        time.sleep(0.4)
        return x

    # A process started in the background by a non-interactive shell inherits SIGINT ignored,
    # and then interrupt_main does nothing: give the test Python's own Ctrl-C handler.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        gen = prefetched(range(100), slow, 2)
        timer = threading.Timer(0.1, _thread.interrupt_main)  # a Ctrl-C while the queue is empty
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            next(gen)
        timer.join()
    finally:
        signal.signal(signal.SIGINT, previous)
    assert not workers_alive()


# ---------------------------------------------------------------------------- measuring
def test_throughput_is_a_pure_summary():
    pace = throughput(10.0, [0.02] * 99 + [5.0], [0.08] * 100)
    assert pace.sweeps == 100 and pace.wall_per_sweep_s == pytest.approx(0.1)
    assert pace.sweeps_per_s == pytest.approx(10.0)
    assert pace.load_median_s == pytest.approx(0.02) and pace.step_median_s == pytest.approx(0.08)
    assert pace.bound_s == pytest.approx(0.08) and pace.ratio == pytest.approx(1.25)
    line = pace.format()
    assert "100.0 ms per sweep" in line and "10.00 sweeps/s" in line and "= 1.25" in line
    assert throughput(1.0, [0.1], [0.2], sweeps=4).wall_per_sweep_s == 0.25
    empty = throughput(0.0, [], [])
    assert empty.sweeps == 0 and math.isnan(empty.ratio) and math.isnan(empty.sweeps_per_s)
