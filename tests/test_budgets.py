"""Budgets are wall-clock promises (issue 51, item 3), tested on a machine slowed on purpose: every simulated
drive sleeps first (`slow_machine`), and the process is held to one core where the OS allows it.

`radar-odom train --minutes` covers simulating the drives, training and validating: simulation stops at its
share of the budget and says how many drives of how many it made ready; a validation pass scores as many pairs
as fit its share; when the budget leaves no time to validate, the latest weights are kept unvalidated. `radar-odom
export` of a checkpoint never calibrated calibrates within --calibration-minutes on as many drives and pairs as
fit, and says how many. Small: the tests' 64 px profile, toy drives in place of the simulator's."""
import json
import math
import os
import re
import time

import pytest

torch = pytest.importorskip("torch")

from radar_odom_export import calibrate as cal  # noqa: E402
from radar_odom_export import data as D  # noqa: E402
from radar_odom_export import train as T  # noqa: E402

pytestmark = pytest.mark.torch

TINY = dict(name="tiny", resolution_m=1.6, width_px=64, max_translation_m=4.8, rotation_range_rad=3 * math.pi / 180,
            rotation_step_rad=math.pi / 180, unet_base_channels=4, unet_depth=3)


class SlowMachine:
    """What the `slow_machine` fixture gives: seconds each simulated drive sleeps first, and the drives made."""

    def __init__(self):
        self.drive_s = 1.5
        self.made = []


@pytest.fixture
def slow_machine(tmp_path, monkeypatch):
    """A slow machine: each simulated drive (a toy drive, not the simulator) takes ``drive_s`` seconds more, the
    simulation runs in this process (the pool's spawned workers would not see the sleep: its own test is
    `test_a_pool_abandons_the_drives_in_flight_at_its_deadline`), and the process keeps to one core where the
    OS lets it. The drive cache is the test's own."""
    slow = SlowMachine()

    def simulate(profile, spec, seconds=None):  # as the simulator: its sweeps one after another, cut at ``seconds``
        per_sweep = slow.drive_s / spec.frames
        n = spec.frames if seconds is None else min(spec.frames, max(D.MIN_CUT_FRAMES, math.ceil(seconds / per_sweep)))
        time.sleep(per_sweep * n)
        slow.made.append(spec.name)
        return D.toy_drive(profile, n, spec.seed, name=spec.name)

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(D, "simulate_drive_arrays", simulate)
    monkeypatch.setattr(D, "_build_in_pool", lambda todo, plan, bar: (setattr(plan, "workers", 1),
                                                                      D._build_in_turn(todo, plan, bar)))
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    if cores:
        os.sched_setaffinity(0, {min(cores)})
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield slow
    torch.set_num_threads(old)
    if cores:
        os.sched_setaffinity(0, cores)


def _profile(tmp_path):
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps(TINY))
    return str(path)


# ----------------------------------------------------------------------------- simulating within a share
def test_simulation_stops_at_its_deadline_keeping_every_scenario_and_at_least_one_drive(slow_machine):
    from radar_odom.profiles import GridProfile

    slow_machine.drive_s = 0.3

    prof = GridProfile.from_dict(TINY)
    specs = D.sim_specs([1000, 1001, 1002, 1003], ["urban", "open"], 4)  # scenario-major: urban first
    report = {}
    drives = D.build_drives(prof, specs, 1, deadline=time.perf_counter() + 0.75, report=report)
    # 0.3 s a drive: the third would end after the deadline, so it is not begun
    assert 1 <= len(drives) <= 3 and report["ready"] == len(drives) and report["asked"] == 8
    assert report["left_out"] == 8 - len(drives) and report["simulated"] == len(drives) and report["cached"] == 0
    assert slow_machine.made[:2] == ["urban-1000", "open-1000"]  # round-robin over the scenarios
    assert [d.name for d in drives] == [s.name for s in specs if s.name in slow_machine.made]  # in specs' order
    # a deadline already passed: the cached drives, and one more (the floor) only where none is cached
    report = {}
    again = D.build_drives(prof, specs, 1, deadline=time.perf_counter() - 1.0, report=report)
    assert len(again) == len(drives) and report["simulated"] == 0
    made = len(slow_machine.made)
    other = D.sim_specs([1010, 1011], ["highway"], 4)
    assert len(D.build_drives(prof, other, 1, deadline=time.perf_counter() - 1.0)) == 1
    assert len(slow_machine.made) == made + 1
    assert D.build_drives(prof, other, 1, deadline=-math.inf, min_drives=0)[0].name == "highway-1010"
    # no deadline: every drive, as before
    assert len(D.build_drives(prof, specs, 1)) == 8


def test_a_pool_abandons_the_drives_in_flight_at_its_deadline(tmp_path, monkeypatch):
    """The simulator itself on a spawned pool of two: past the deadline, once a drive is ready, the drive still in
    flight is abandoned and its half-written file removed; with ``cut``, the drives are cut short in the workers."""
    from radar_odom.profiles import GridProfile

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    specs = D.sim_specs([1000, 1001, 1002, 1003], ["urban"], 3)
    report = {}
    t0 = time.perf_counter()
    drives = D.build_drives(GridProfile.from_dict(TINY), specs, 2, with_labels=False, deadline=t0 + 0.2,
                            report=report)
    assert 1 <= len(drives) <= 2 and report["left_out"] == 4 - len(drives)
    assert not list((tmp_path / "cache" / "drives").glob(".*.tmp"))
    # cut short instead (as calibration does): each drive its share of the time left, ended there, not cached
    specs = D.sim_specs([2500], ["open", "highway"], 200)
    report = {}
    drives = D.build_drives(GridProfile.from_dict(TINY), specs, 2, with_labels=False,
                            deadline=time.perf_counter() + 2.0, report=report, cut=True)
    assert 1 <= len(drives) == report["cut_short"] <= 2
    assert all(D.MIN_CUT_FRAMES <= len(x.images) < 200 and x.labels is None for x in drives)
    assert report["sweeps"] == [sum(len(x.images) for x in drives), 400]
    assert not [f for f in (tmp_path / "cache" / "drives").iterdir() if "2500" in f.name]


# ----------------------------------------------------------------------------- train --minutes
def test_train_with_slow_simulation_writes_a_checkpoint_within_its_budget(slow_machine, tmp_path, capsys):
    """0.2 minutes, 12 training and 4 validation drives asked at 1.5 s each: simulating stops at 40 % (4.8 s)
    and 10 % more, and the checkpoint is written by the end of the budget, give or take the last save."""
    from radar_odom.commands.cli import main
    from radar_odom_export.checkpoint import read_checkpoint_dict

    ckpt = tmp_path / "m.pt"
    budget_s = 0.2 * 60
    t0 = time.perf_counter()
    assert main(["train", "-o", str(ckpt), "--profile", _profile(tmp_path), "--sim-seeds", "1000-1005",
                 "--val-seeds", "2000-2001", "--scenarios", "urban,open", "--frames", "10", "--minutes", "0.2",
                 "--workers", "1", "--threads", "1", "--batch", "4", "--epochs", "500"]) == 0
    elapsed = time.perf_counter() - t0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[0].startswith("train: 0.2-minute budget (--minutes) for all of it") and "stops by" in out[0]
    said = re.match(r"train: (\d+) of 12 training drives and (\d+) of 4 validation drives ready \((\d+) simulated",
                    out[1])
    assert said, out[1]
    n_train, n_val = int(said[1]), int(said[2])
    assert 1 <= n_train <= 4 and n_val == 1 and int(said[3]) == n_train + n_val  # 4.8 s / 1.5 s; 1.2 s / 1.5 s
    assert f"{16 - n_train - n_val} left out to keep the 0.2-minute budget" in out[1]
    assert elapsed < budget_s + T.GRACE_S, elapsed  # the grace: a last save, the loss plot, a loaded machine
    record = read_checkpoint_dict(ckpt)["train"]
    assert record["stopped_by_budget"] and record["steps"] >= 1 and len(record["train_drives"]) == n_train
    assert math.isfinite(record["best_val"])  # a validated epoch
    assert out[-1].startswith(f"wrote {ckpt}: best validation pose error") and "stopped by the 0.2-minute" in out[-1]


# ----------------------------------------------------------------------------- no time left to validate
@pytest.fixture(scope="module")
def toy():
    from radar_odom.profiles import GridProfile

    prof = GridProfile.from_dict(TINY)
    return prof, [D.toy_drive(prof, 8, s) for s in (1, 2)], [D.toy_drive(prof, 60, s) for s in (3, 4)]


def _cfg(tmp_path, prof, **kw):
    return T.TrainConfig(output=str(tmp_path / "m.pt"), profile=prof, batch=4, threads=1, pose_loss="ce", **kw)


def test_a_spent_budget_keeps_the_latest_weights_unvalidated(toy, tmp_path):
    """The drives took the whole budget (and more than the grace): one step, no validation pass begun, the
    latest weights written and said to be unvalidated."""
    prof, train_d, val_d = toy
    cfg = _cfg(tmp_path, prof, epochs=3, minutes=0.05, started=time.perf_counter() - 60.0)
    summary = T.train(cfg, train_d, val_d)
    assert summary["steps"] == 1 and summary["kept_unvalidated"] and summary["stopped_by_budget"]
    log = json.loads(T.log_path(cfg.output).read_text())
    assert [e["validated"] for e in log["epochs"]] == [False]
    from radar_odom_export.checkpoint import load_checkpoint

    model, meta = load_checkpoint(cfg.output)  # a whole checkpoint, the weights after that step
    assert meta["train"]["best_epoch"] == 1 and meta["train"]["kept_unvalidated"]
    line = T.final_line(cfg.output, summary, prof, budget_minutes=0.05)
    assert "the weights of epoch 1, not validated: the 0.05-minute budget ended" in line and "1 step," in line


def test_a_resumed_run_without_time_to_validate_keeps_the_validated_best(toy, tmp_path):
    prof, train_d, val_d = toy
    from radar_odom_export.checkpoint import read_checkpoint_dict

    first = T.train(_cfg(tmp_path, prof, epochs=1), train_d, val_d)
    assert math.isfinite(first["best_val"]) and first["best_epoch"] == 1
    kept = read_checkpoint_dict(tmp_path / "m.pt")["state_dict"]
    cfg = _cfg(tmp_path, prof, epochs=3, minutes=0.05, started=time.perf_counter() - 60.0, resume=True)
    summary = T.train(cfg, train_d, val_d)
    assert summary["best_epoch"] == 1 and summary["best_val"] == first["best_val"] and not summary["kept_unvalidated"]
    st = T.read_resume_state(cfg.output)
    assert st["epoch"] == 2 and st["step"] == first["steps"] + 1  # the latest weights go on in the state
    after = read_checkpoint_dict(cfg.output)
    assert after["train"]["best_epoch"] == 1  # the validated weights, not the step after them
    assert all(torch.equal(after["state_dict"][k], v) for k, v in kept.items())
    assert "best validation pose error" in T.final_line(cfg.output, summary, prof, budget_minutes=0.05)


def test_validation_scores_the_pairs_that_fit_its_share_of_the_budget(toy, tmp_path):
    """118 validation pairs and a 1.2 s budget: one pass may take a tenth of it, so it scores fewer pairs,
    spread over both drives, the same ones each epoch."""
    prof, train_d, val_d = toy
    cfg = _cfg(tmp_path, prof, epochs=50, minutes=0.02, started=time.perf_counter())
    summary = T.train(cfg, train_d, val_d)
    assert summary["val_pairs_asked"] == 118 and 4 <= summary["val_pairs"] < 118
    if math.isfinite(summary["best_val"]):
        assert f"validated on {summary['val_pairs']} of 118 validation pairs" in T.final_line(
            cfg.output, summary, prof, budget_minutes=0.02)
    assert T._spread(118, 10) == [0, 13, 26, 39, 52, 65, 78, 91, 104, 117]


def test_a_validation_pass_past_its_deadline_is_abandoned(toy):
    prof, _, val_d = toy
    from radar_odom_export.model import MaskedCorrelator

    objective = T.Objective(MaskedCorrelator(prof), "pose", 1.0, "ce")
    val = D.PairDataset(val_d)
    assert T.validation_stats(objective, val, 8, T.Dist(), deadline=time.perf_counter() - 1) is None
    assert objective.training  # left as it was found
    stats = T.validation_stats(objective, D.PairDataset(val_d[:1]), 64, T.Dist(), deadline=time.perf_counter() + 60)
    assert stats is not None and math.isfinite(stats["loss"])


# ----------------------------------------------------------------------------- export's calibration
def test_calibration_within_a_budget_takes_the_pairs_that_fit_spread_over_every_drive(tmp_path):
    from radar_odom.profiles import GridProfile
    from radar_odom_export.checkpoint import read_checkpoint_dict, save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    prof = GridProfile.from_dict(TINY)
    drives = [D.toy_drive(prof, 40, s, noise=0.3, name=f"{sc}-{s}") for s, sc in ((21, "urban"), (22, "open"))]
    path = save_checkpoint(tmp_path / "raw.pt", MaskedCorrelator(prof, masking="raw"), "raw")
    res = cal.calibrate_checkpoint(path, drives, search="fast", work_by=time.perf_counter() - 1.0)
    # the budget spent already: one batch of volumes and one window of estimates, from the first drive's start
    assert res.coverage == {"volumes": [8, 78], "estimates": [8, 78]} and res.pairs == 8
    assert read_checkpoint_dict(path)["calibration"]["coverage"] == res.coverage
    order = cal.spread_order(10)
    assert sorted(order) == list(range(10)) and order[:4] == [0, 4, 8, 1]


def test_a_temperature_out_of_reach_leaves_the_scale_to_the_per_axis_fit(tmp_path, monkeypatch):
    """A few easy drives (what a short budget may leave): no temperature brings mean d² into the band. The fitted
    covariance keeps beta_cov at beta_pose, sets its scale by maximum likelihood and says so; the temperature
    alone still stops with the table."""
    from radar_odom.profiles import GridProfile
    from radar_odom_export.checkpoint import read_checkpoint_dict, save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    def out_of_reach(mean_d2, beta0, **kw):
        raise cal.CalibrationError("no temperature brings mean d² to 3", table=[(beta0, mean_d2(beta0)), (1e4, 2.2)])

    monkeypatch.setattr(cal, "calibrate_beta", out_of_reach)
    prof = GridProfile.from_dict(TINY)
    drives = [D.toy_drive(prof, 20, s, noise=0.3, name=f"urban-{s}") for s in (21, 22)]
    path = save_checkpoint(tmp_path / "raw.pt", MaskedCorrelator(prof, masking="raw"), "raw")
    res = cal.calibrate_checkpoint(path, drives, search="fast")
    assert res.beta_cov == prof.beta_pose and res.mean_d2 == pytest.approx(3.0, rel=0.05)
    assert "beta_cov kept at beta_pose = 1" in res.note and res.table[-1] == (1e4, 2.2)
    assert read_checkpoint_dict(path)["calibration"]["note"] == res.note
    with pytest.raises(cal.CalibrationError, match="no temperature"):
        cal.calibrate_checkpoint(path, drives, output=tmp_path / "t.pt", covariance="temperature")


def test_export_of_a_fresh_checkpoint_calibrates_within_its_budget(slow_machine, tmp_path, monkeypatch, capsys):
    """A checkpoint never calibrated, a slow machine (each simulated drive 1.5 s, each batch of correlation
    volumes and each window of search estimates 0.3 s more): the calibration simulates every scenario, each drive
    cut short, within a quarter of the 0.25-minute budget, stops by 70 % of it and says on how many drives, sweeps
    and pairs of how many; the export ends within the budget."""
    from radar_odom.commands.cli import main
    from radar_odom.profiles import GridProfile
    from radar_odom_export.checkpoint import read_checkpoint_dict, save_checkpoint
    from radar_odom_export.fast_search import FastSequenceStep
    from radar_odom_export.model import MaskedCorrelator

    def slowed(fn):
        def wrapper(*args, **kwargs):
            time.sleep(0.3)
            return fn(*args, **kwargs)
        return wrapper

    monkeypatch.setattr(MaskedCorrelator, "correlation_volume", slowed(MaskedCorrelator.correlation_volume))
    monkeypatch.setattr(FastSequenceStep, "forward", slowed(FastSequenceStep.forward))
    done = {}
    real = cal.calibrate_checkpoint

    def timed(*args, **kwargs):
        out = real(*args, **kwargs)
        done["at"] = time.perf_counter()
        return out

    monkeypatch.setattr(cal, "calibrate_checkpoint", timed)
    ckpt = save_checkpoint(tmp_path / "m.pt", MaskedCorrelator(GridProfile.from_dict(TINY), masking="raw"), "raw")
    budget_s = 0.25 * 60
    t0 = time.perf_counter()
    assert main(["export", str(ckpt), "--calibration-minutes", "0.25", "--threads", "1", "--no-verify",
                 "--exporter", "torchscript"]) == 0
    elapsed = time.perf_counter() - t0
    out = capsys.readouterr().out
    assert "within the 0.25-minute budget of this export (--calibration-minutes)" in out
    # by 70 % of the budget, give or take the fit, the checkpoint's write and a loaded machine
    assert done["at"] - t0 < cal.EXPORT_WORK_SHARE * budget_s + 3.0, done["at"] - t0
    said = re.search(r"calibration: (\d) of 4 drives \((\d+) of 480 sweeps: cut short\), the temperature on (\d+) "
                     r"of (\d+) pairs, the per-axis shape on (\d+) of (\d+), in [\d.]+ min: as many as fit in the "
                     r"0.25-minute budget", out)
    assert said, out
    n_drives, sweeps, vols, vols_there, est, est_there = map(int, said.groups())
    # 3.75 s for 4 drives of 1.5 s: each is cut short, rather than the last scenarios left out
    assert n_drives >= 2 and sweeps < 480 and vols_there == est_there == sweeps - n_drives
    assert slow_machine.made[:2] == ["urban-2500", "heavy_traffic-2500"]
    assert 8 <= vols < vols_there and 8 <= est < est_there
    assert read_checkpoint_dict(ckpt)["calibration"]["coverage"] == {"volumes": [vols, vols_there],
                                                                   "estimates": [est, est_there]}
    assert (tmp_path / "m.onnx").is_file() and "export: " in out and "min in all" in out
    assert elapsed < budget_s + T.GRACE_S, elapsed


def test_calibration_minutes_beyond_a_week_are_refused_before_any_work(tmp_path, capsys):
    from radar_odom.commands.cli import main
    from radar_odom.profiles import GridProfile
    from radar_odom_export.checkpoint import save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    ckpt = save_checkpoint(tmp_path / "m.pt", MaskedCorrelator(GridProfile.from_dict(TINY), masking="raw"), "raw")
    for bad in ("1e308", "-1", "nan"):
        assert main(["export", str(ckpt), "--calibration-minutes", bad]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"--calibration-minutes {bad}" in err[0].replace("1e+308", "1e308"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pt"]
