"""`radar-odom adapt` (`radar_odom_export.adapt`): the vehicle-chord labels, the direction bias, the
held-out split, the collapse guard, self-consistency on simulated sweeps, and a whole run from a
small learned checkpoint on a simulated recording (its files, metadata, report and refusals)."""
import json
import math

import numpy as np
import pytest

from radar_odom.errors import ConfigError, SequenceError

pytest.importorskip("radar_odom_export", reason="adapt is the torch side's (radar-odom-export, export/): not installed")

from radar_odom_export.adapt import (  # noqa: E402
    AdaptConfig,
    check_collapse,
    direction_bias_deg,
    holdout_split,
    parse_sweeps,
    vehicle_chord,
)


def test_vehicle_chord_keeps_length_and_yaw_and_points_at_half_the_turn():
    rel = np.array([[2.0, -0.1, 0.02], [1.0, 0.3, -0.04], [-1.5, 0.05, 0.01], [0.1, 0.05, 0.3], [np.nan, 0, 0]])
    out = vehicle_chord(rel)
    moved = slice(0, 3)
    np.testing.assert_allclose(np.hypot(out[moved, 0], out[moved, 1]), np.hypot(rel[moved, 0], rel[moved, 1]))
    np.testing.assert_array_equal(out[:, 2], rel[:, 2])
    np.testing.assert_allclose(np.arctan2(out[:2, 1], out[:2, 0]), rel[:2, 2] / 2)
    # backwards: along the chord, the other way (x < 0), still half the turn off the axis
    assert out[2, 0] < 0 and math.isclose(math.atan2(-out[2, 1], -out[2, 0]), rel[2, 2] / 2)
    np.testing.assert_array_equal(out[3], rel[3])  # too short to have a direction
    assert np.isnan(out[4, 0])


def test_vehicle_chord_is_the_arc_a_no_slip_car_drives():
    # a car on a circle of radius 40 m, one step of 2 m of arc: the radar on its axis moves along the chord
    radius, arc = 40.0, 2.0
    yaw = arc / radius
    truth = np.array([radius * math.sin(yaw), radius * (1 - math.cos(yaw)), yaw])
    slid = truth.copy()
    slid[1] -= 0.05  # a matcher whose step points 1.4° right of travel
    np.testing.assert_allclose(vehicle_chord(slid[None])[0, 1] / vehicle_chord(slid[None])[0, 0],
                               truth[1] / truth[0], rtol=1e-9)


def test_direction_bias_is_measured_on_straight_forward_steps():
    rel = np.tile([2.0, 2.0 * math.tan(math.radians(-1.5)), 0.0], (10, 1))
    rel[3] = [0.2, 0.1, 0.0]  # too short
    rel[5] = [2.0, 0.5, math.radians(3.0)]  # a turn
    assert direction_bias_deg(rel) == pytest.approx(-1.5, abs=1e-9)
    assert math.isnan(direction_bias_deg(np.zeros((4, 3))))


def test_holdout_split_and_sweeps_parse():
    assert holdout_split(200, 0.2) == 160
    assert holdout_split(18, 0.2) == 14  # at least 4 held out (RADIATE fog_6_0 has 18 sweeps)
    with pytest.raises(SequenceError, match="fewer than 8"):
        holdout_split(11, 0.2)
    with pytest.raises(ConfigError):
        holdout_split(100, 1.0)
    assert parse_sweeps(":200") == slice(None, 200) and parse_sweeps("10:") == slice(10, None)
    assert parse_sweeps(None) == slice(None)
    with pytest.raises(ConfigError, match="A:B"):
        parse_sweeps("200")


def test_collapse_guard_refuses_a_model_that_stands_still():
    shipped = {"mean_step_m": 1.3}
    assert check_collapse(shipped, {"mean_step_m": 1.25}) is None
    assert "standing still" in check_collapse(shipped, {"mean_step_m": 0.4})
    assert check_collapse({"mean_step_m": 0.0}, {"mean_step_m": 0.0}) is None  # a parked car: nothing to compare
    assert check_collapse(shipped, {"mean_step_m": float("nan")}) is not None


@pytest.fixture(scope="module")
def sim_drive(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("sim") / "drive", seed=21, frames=24, progress=False)


def test_self_consistency_of_a_model_on_simulated_sweeps(sim_drive, cli_model):
    from radar_odom.io import read_sequence
    from radar_odom_export.adapt import self_consistency

    seq = read_sequence(sim_drive)
    scans = [seq.scan(i) for i in range(12)]
    sc = self_consistency(cli_model, scans)
    assert sc["pairs"] == 11
    assert 0.0 <= sc["composition_t_m"] < 5.0 and 0.0 <= sc["composition_yaw_deg"] < 10.0
    assert sc["mean_step_m"] > 0.3  # the simulated car drives ~1 m per sweep; a raw model sees it


@pytest.fixture(scope="module")
def small_checkpoint(tmp_path_factory):
    torch = pytest.importorskip("torch")
    from radar_odom_export.checkpoint import save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    from fixtures.make_models import CLI

    torch.manual_seed(0)
    # the fast search's polar rotation needs a yaw step that divides the turn
    profile = CLI.with_(name="adapt-test", near_range_m=2.5, rotation_step_rad=math.radians(1.5),
                        rotation_range_rad=math.radians(6.0))
    model = MaskedCorrelator(profile, masking="learned")
    return save_checkpoint(tmp_path_factory.mktemp("ckpt") / "small.pt", model, "learned", train={})


@pytest.mark.slow
@pytest.mark.torch
def test_adapt_writes_model_checkpoint_and_report(sim_drive, small_checkpoint, tmp_path):
    from radar_odom import RadarOdometer
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.adapt import adapt, format_report
    from radar_odom_export.checkpoint import read_checkpoint_dict

    cfg = AdaptConfig(base=str(small_checkpoint), minutes=0.05, epochs=1, sim_seeds=(1000,), sim_frames=6,
                      sim_scenarios=("urban",), threads=1, keep="fine-tuned")
    out = tmp_path / "mine.onnx"
    report = adapt([sim_drive], out, cfg)
    assert out.is_file() and out.with_suffix(".pt").is_file()
    saved = json.loads(out.with_suffix(".adapt.json").read_text())
    assert saved["format"] == "radar-odom-adapt/1" and saved["refused"] == []
    assert saved["kept"] == "fine-tuned" and saved["kept_because"] == "--keep fine-tuned"
    rec = saved["recordings"][0]
    assert rec["sweeps"] == 24 and rec["held_out_from"] == 19  # the last 20 % held out
    for who in ("shipped", "base", "fine-tuned"):
        assert rec["self_consistency"][who]["pairs"] == 4
    assert "too short" in rec["reference"]  # 5 simulated sweeps are no KITTI segment
    assert "self-consistency" in format_report(report)
    info = OnnxModel(out).info
    assert info.form == "stream" and info.search["kind"] == "coarse_to_fine"
    mount = saved["mount_yaw_deg"]["fine-tuned"]  # 19 sweeps of a simulated drive: straight enough?
    assert info.mount_yaw_rad == pytest.approx(0.0 if mount is None else math.radians(mount))
    ckpt = read_checkpoint_dict(out.with_suffix(".pt"))
    assert ckpt["train"]["adapted_from"] == "small.pt" and ckpt["train"]["adapt"]["vehicle_prior"] is True
    odo = RadarOdometer(out)
    from radar_odom.io import read_sequence

    seq = read_sequence(sim_drive)
    for i in range(3):
        odo.step(seq.scan(i))
    assert len(odo.trajectory.poses) == 3


@pytest.mark.torch
def test_adapt_refuses_bad_requests_before_any_work(sim_drive, small_checkpoint, tmp_path):
    from radar_odom.commands.cli import main
    from radar_odom_export.adapt import adapt

    with pytest.raises(ConfigError, match=r"\.onnx"):
        adapt([sim_drive], tmp_path / "mine.pt", AdaptConfig(base=str(small_checkpoint)))
    with pytest.raises(ConfigError, match="minutes"):
        adapt([sim_drive], tmp_path / "mine.onnx", AdaptConfig(base=str(small_checkpoint), minutes=0))
    with pytest.raises(SequenceError, match="at least"):
        adapt([sim_drive], tmp_path / "mine.onnx", AdaptConfig(base=str(small_checkpoint)), sweeps=slice(0, 11))
    (tmp_path / "exists.onnx").write_bytes(b"x")
    assert main(["adapt", str(sim_drive), "-o", str(tmp_path / "exists.onnx")]) != 0


def test_adapt_help_defaults_match_the_config():
    import argparse

    from radar_odom_export.commands import adapt as cmd

    sub = argparse.ArgumentParser().add_subparsers()
    cmd.register(sub)
    p = sub.choices["adapt"]
    args = p.parse_args(["rec", "-o", "x.onnx"])
    d = AdaptConfig()
    assert (args.base, args.minutes, args.epochs, args.lr, args.real_fraction, args.max_skip, args.holdout) == (
        d.base, d.minutes, d.epochs, d.lr, d.real_fraction, d.max_skip, d.holdout_fraction)


def test_mount_yaw_is_minus_the_straight_steps_direction():
    from radar_odom_export.adapt import mount_yaw_from

    rel = np.tile([2.0, 2.0 * math.tan(math.radians(-1.5)), 0.0], (12, 1))
    assert math.degrees(mount_yaw_from(rel)) == pytest.approx(1.5, abs=1e-9)
    assert mount_yaw_from(rel[:5]) is None  # too few straight steps to say


def test_turn_frame_is_the_conjugation_by_the_mount():
    from radar_odom.se2 import invert, se2, to_xyyaw, turn_frame

    pose, cov = np.array([2.0, -0.05, 0.01]), np.diag([0.01, 0.04, 1e-4])
    m = math.radians(1.5)
    turned, turned_cov = turn_frame(pose, cov, m)
    mount = se2(0.0, 0.0, m)
    np.testing.assert_allclose(turned, to_xyyaw(mount @ se2(*pose) @ invert(mount)), atol=1e-12)
    assert np.trace(turned_cov) == pytest.approx(np.trace(cov)) and np.allclose(turned_cov, turned_cov.T)
    back, back_cov = turn_frame(turned, turned_cov, -m)
    np.testing.assert_allclose(back, pose, atol=1e-12)
    np.testing.assert_allclose(back_cov, cov, atol=1e-15)
    many, many_cov = turn_frame(np.stack([pose, back]), np.stack([cov, back_cov]), m)  # batches: row by row
    np.testing.assert_allclose(many, np.stack([turned, turned]), atol=1e-12)
    np.testing.assert_allclose(many_cov, np.stack([turned_cov, turned_cov]), atol=1e-15)


@pytest.mark.torch
def test_a_mount_yaw_in_the_file_turns_every_match(sim_drive, tmp_path):
    import shutil

    pytest.importorskip("onnx")
    from conftest import fixture_file

    from radar_odom import RadarOdometer
    from radar_odom.io import read_sequence
    from radar_odom.onnx_model import OnnxModel
    from radar_odom.se2 import turn_frame
    from radar_odom_export.adapt import set_mount_yaw

    seq = read_sequence(sim_drive)
    scans = [seq.scan(i) for i in range(6)]
    plain = fixture_file("cli-raw.onnx")
    mounted = tmp_path / "mounted.onnx"
    shutil.copy(plain, mounted)
    m = math.radians(2.0)
    set_mount_yaw(mounted, m)
    assert OnnxModel(mounted).info.mount_yaw_rad == pytest.approx(m)
    a, b = RadarOdometer(plain, motion_prior=False), RadarOdometer(mounted, motion_prior=False)
    for scan in scans:
        ea, eb = a.step(scan), b.step(scan)
        if ea is not None:
            want, want_cov = turn_frame(ea.pose, ea.covariance, m)
            np.testing.assert_allclose(eb.pose, want, atol=1e-9)
            np.testing.assert_allclose(eb.covariance, want_cov, atol=1e-12)
    with pytest.raises(Exception, match="mount_yaw_rad"):
        set_mount_yaw(mounted, 2.0)  # beyond ±45°: refused, the file is left as it was
    assert OnnxModel(mounted).info.mount_yaw_rad == pytest.approx(m)


@pytest.mark.torch
def test_a_mount_yaw_turns_the_batched_matches_too(tmp_path):
    import shutil

    pytest.importorskip("onnx")
    from conftest import fixture_file

    from radar_odom import match_sequence
    from radar_odom.onnx_model import OnnxModel
    from radar_odom.se2 import turn_frame
    from radar_odom_export.adapt import set_mount_yaw

    plain = fixture_file("small-fast-seq.onnx")
    mounted = tmp_path / "mounted-seq.onnx"
    shutil.copy(plain, mounted)
    set_mount_yaw(mounted, -0.03)
    shape = OnnxModel(plain).info.input_shape[1:]
    x = np.random.default_rng(0).random((5, *shape)).astype(np.float32)
    a, b = match_sequence(plain, x, batch=2), match_sequence(mounted, x, batch=2)
    for k in range(4):
        want, want_cov = turn_frame(a.poses[k], a.covariances[k], -0.03)
        np.testing.assert_allclose(b.poses[k], want, atol=1e-9)
        np.testing.assert_allclose(b.covariances[k], want_cov, atol=1e-12)


def test_choose_masker_keeps_the_fine_tune_only_where_its_matches_compose_as_well():
    from radar_odom_export.adapt import choose_masker

    def sc(t, yaw, pairs=40):
        return [{"composition_t_m": t, "composition_yaw_deg": yaw, "pairs": pairs}]

    assert choose_masker({"base": sc(0.08, 0.26), "fine-tuned": sc(0.07, 0.25)})[0] == "fine-tuned"
    kept, why = choose_masker({"base": sc(0.082, 0.261), "fine-tuned": sc(0.096, 0.278)})  # the shared drive's
    assert kept == "base" and "translation and yaw" in why
    kept, why = choose_masker({"base": sc(0.08, 0.26), "fine-tuned": sc(0.07, 0.30)})
    assert kept == "base" and "yaw" in why and "translation" not in why
    assert choose_masker({"base": sc(0.08, 0.26), "fine-tuned": sc(0.09, 0.30)}, keep="fine-tuned")[0] == "fine-tuned"
    kept, why = choose_masker({"base": sc(0.08, 0.26), "fine-tuned": sc(0.01, 0.01)}, refused=["x: collapsed"])
    assert kept == "base" and "collapsed" in why


@pytest.mark.slow
@pytest.mark.torch
def test_adapt_writes_the_base_masker_with_its_mount_when_the_fine_tune_does_not_win(sim_drive, small_checkpoint,
                                                                                      tmp_path):
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.adapt import adapt
    from radar_odom_export.checkpoint import read_checkpoint_dict

    cfg = AdaptConfig(base=str(small_checkpoint), minutes=0.05, epochs=1, sim_seeds=(1000,), sim_frames=6,
                      sim_scenarios=("urban",), threads=1, keep="base")
    out = tmp_path / "mine.onnx"
    report = adapt([sim_drive], out, cfg)
    assert report["kept"] == "base"
    ckpt = read_checkpoint_dict(out.with_suffix(".pt"))
    base = read_checkpoint_dict(small_checkpoint)
    for k, v in base["state_dict"].items():
        assert torch_equal(ckpt["state_dict"][k], v), k
    assert ckpt["train"]["adapt"]["kept"] == "base"
    assert out.with_suffix(".fine-tuned.pt").is_file()  # the fine-tune, kept aside
    mount = report["mount_yaw_deg"]["base"]
    assert OnnxModel(out).info.mount_yaw_rad == pytest.approx(0.0 if mount is None else math.radians(mount))


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


@pytest.mark.slow
@pytest.mark.torch
def test_adapt_reads_a_ros_bag_as_run_does(sim_drive, small_checkpoint, tmp_path):
    pytest.importorskip("rosbags")
    from test_bags import write_bag

    from radar_odom.io import read_sequence
    from radar_odom_export.adapt import adapt

    seq = read_sequence(sim_drive)
    bag = write_bag(tmp_path / "drive.mcap", [seq.scan(i) for i in range(len(seq))], kind="bscan")
    cfg = AdaptConfig(base=str(small_checkpoint), minutes=0.05, epochs=1, sim_seeds=(1000,), sim_frames=6,
                      sim_scenarios=("urban",), threads=1)
    report = adapt([bag], tmp_path / "from-bag.onnx", cfg)
    rec = report["recordings"][0]
    assert rec["name"] == "drive.mcap" and rec["sweeps"] == 24 and rec["reference"] == "no reference in the recording"
    assert (tmp_path / "from-bag.onnx").is_file()


@pytest.mark.torch
def test_labels_on_one_rank_come_from_the_local_labeller_or_the_cluster_in_recording_order():
    pytest.importorskip("torch")  # Dist lives with train's torch code
    from radar_odom_export.adapt import labels_on_ranks
    from radar_odom_export.train import Dist

    assert labels_on_ranks(Dist(), 3, lambda k: ("local", k)) == [("local", 0), ("local", 1), ("local", 2)]
    assert labels_on_ranks(Dist(), 2, None, lambda: ["a", "b"]) == ["a", "b"]


@pytest.mark.slow
@pytest.mark.torch
def test_adapt_under_torchrun_trains_on_two_ranks_and_rank_0_alone_writes(sim_drive, small_checkpoint, tmp_path):
    """`torchrun --nproc_per_node=2 -m radar_odom adapt`: two recordings (one labelled by each rank, then
    gathered), DDP training with both ranks in step, one model, checkpoint and report, printed once."""
    import os
    import subprocess
    import sys

    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.checkpoint import read_checkpoint_dict

    out = tmp_path / "out" / "mine.onnx"
    out.parent.mkdir()
    env = {**os.environ, "RADAR_ODOM_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "-m", "radar_odom", "adapt", str(sim_drive), str(sim_drive), "-o", str(out), "--from", str(small_checkpoint),
           "--minutes", "0.05", "--epochs", "1", "--threads", "1", "--keep", "fine-tuned"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    assert sorted(p.name for p in out.parent.iterdir()) == [
        "mine.adapt.json", "mine.log.json", "mine.loss.png", "mine.onnx", "mine.pt", "mine.state.pt"]
    assert OnnxModel(out).info.form == "stream"
    rec = read_checkpoint_dict(out.with_suffix(".pt"))["train"]
    assert rec["world_size"] == 2 and rec["ranks_in_sync"] is True
    assert rec["rank_steps"][0] == rec["rank_steps"][1] == rec["steps"] > 0
    report = json.loads(out.with_suffix(".adapt.json").read_text())
    assert [r["sweeps"] for r in report["recordings"]] == [24, 24]
    assert proc.stdout.count("self-consistency (graph alone)") == 2  # one report, a table per recording
    assert proc.stdout.count(f"wrote {out},") == 1


def test_the_budget_covers_simulating_and_leaves_training_at_least_its_share():
    from radar_odom_export.adapt import SIM_SHARE, training_minutes

    assert training_minutes(12.0, 0.0) == 12.0  # drives cached: all of it trains
    assert training_minutes(12.0, 60.0) == pytest.approx(11.0)
    assert training_minutes(12.0, 3600.0) == pytest.approx((1 - SIM_SHARE) * 12.0)  # one slow drive it had to finish


@pytest.mark.slow
@pytest.mark.torch
def test_adapt_gives_the_simulation_a_deadline_within_its_budget(sim_drive, small_checkpoint, tmp_path, monkeypatch):
    import time

    from radar_odom_export import adapt as A
    from radar_odom_export import data as D

    seen = {}
    real = D.build_drives

    def spy(*a, **kw):
        seen.update(kw, at=time.perf_counter())
        return real(*a, **kw)

    monkeypatch.setattr(D, "build_drives", spy)
    cfg = A.AdaptConfig(base=str(small_checkpoint), minutes=0.05, epochs=1, sim_seeds=(1000,), sim_frames=6,
                        sim_scenarios=("urban",), threads=1, keep="fine-tuned")
    A.adapt([sim_drive], tmp_path / "mine.onnx", cfg)
    assert seen["min_drives"] == 1
    assert 0 < seen["deadline"] - seen["at"] <= A.SIM_SHARE * 60 * cfg.minutes + 1e-6
