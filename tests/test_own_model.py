"""A user's own model end to end, as the README's flow gives it: `radar-odom train`, then
`radar-odom export model.pt` (which calibrates the covariance of a checkpoint that never was),
then `RadarOdometer("model.onnx")`. Small: a 64 px profile, a few short simulated recordings."""
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

pytestmark = pytest.mark.torch

# 1.6 m cells, 64 px: a 51 m disc, so the simulated sweeps need 1300 bins (56 m); ±3 yaw steps of 1°
# (a step must divide the turn)
TINY = dict(name="tiny", resolution_m=1.6, width_px=64, max_translation_m=4.8, rotation_range_rad=3 * math.pi / 180,
            rotation_step_rad=math.pi / 180, unet_base_channels=4, unet_depth=3,
            cov_scale=50.0)  # an uncalibrated covariance far too wide (at 1.6 m cells the default is near right)


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """Four short urban recordings: train, validation, calibration, held out."""
    from radar_odom.sim import SimConfig, write_drive

    root = tmp_path_factory.mktemp("own")
    cfg = SimConfig().with_sensor(num_bins=1300)
    frames = {"train": 16, "val": 8, "cal": 24, "held": 24}
    seeds = {"train": 1001, "val": 2001, "cal": 2501, "held": 5001}
    return {k: write_drive(root / k, seed=seeds[k], frames=n, config=cfg, progress=False) for k, n in frames.items()}


def _d2(err, cov):
    return float(err @ np.linalg.solve(cov, err))


def _held_out(model_path, seq_path, motion_prior):
    """(d² of every estimate against the reference, flags of every estimate) over a recording."""
    import radar_odom
    from radar_odom.se2 import wrap_angle

    seq = radar_odom.read_sequence(seq_path)
    odo = radar_odom.RadarOdometer(str(model_path), motion_prior=motion_prior, threads=1)
    d2, flags = [], []
    for k, frame in enumerate(seq):
        est = odo.step(frame.scan)
        if est is None:
            continue
        gt = seq.gt_relative[k - 1]
        err = np.array([est.pose[0] - gt[0], est.pose[1] - gt[1], wrap_angle(est.pose[2] - gt[2])])
        d2.append(_d2(err, np.asarray(est.covariance, np.float64)))
        flags.append(set(est.flags))
    return np.array(d2), flags


@pytest.mark.slow
def test_train_then_export_gives_a_calibrated_fast_search_model(drives, tmp_path, monkeypatch, capsys):
    from radar_odom.commands.cli import main
    from radar_odom.onnx_model import OnnxModel

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    prof = tmp_path / "tiny.json"
    prof.write_text(json.dumps(TINY))
    ckpt = tmp_path / "mine.pt"
    assert main(["train", str(drives["train"]), "--val-data", str(drives["val"]), "-o", str(ckpt),
                 "--profile", str(prof), "--epochs", "1", "--batch", "4", "--threads", "1", "--minutes", "2"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[0].startswith("train: 2-minute budget") and "stops by" in out[0]
    last = out[-1]
    assert last.startswith(f"wrote {ckpt}: best validation pose error ") and "cells²" in last
    assert "validation loss" in last and "(ce, the trained objective)" in last and "1 cell = 1.6 m" in last

    # the uncalibrated export, as a user might force it: one loud line, and the covariance is far off
    raw = tmp_path / "raw.onnx"
    assert main(["export", str(ckpt), "-o", str(raw), "--no-calibrate", "--no-verify"]) == 0
    err = capsys.readouterr().err
    warnings = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warnings) == 1 and warnings[0].startswith("radar-odom export: warning: ") and "never calibrated" in \
        warnings[0]

    # the plain export calibrates first (the d² table), then writes the fast search in the stream form
    assert main(["export", str(ckpt), "--calibration-data", str(drives["cal"]), "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "no calibrated covariance yet: calibrating it first" in out and "| β (beta_cov) | mean d² |" in out
    onnx = tmp_path / "mine.onnx"  # the default name: the fast search is the default, not tagged
    info = OnnxModel(str(onnx), threads=1)
    meta = dict(info.session.get_modelmeta().custom_metadata_map)
    assert json.loads(meta["radar_odom.search"])["kind"] == "coarse_to_fine"
    assert meta.get("radar_odom.form", "stream") == "stream"
    from radar_odom_export.calibrate import is_calibrated

    assert is_calibrated(ckpt)  # written into the checkpoint: a second export does not calibrate again

    # held-out pairs (another world, never trained or calibrated on): the graph's own covariance
    # is a 1σ there; the uncalibrated one is orders of magnitude too wide
    d2, _ = _held_out(onnx, drives["held"], motion_prior=False)
    d2_raw, _ = _held_out(raw, drives["held"], motion_prior=False)
    assert len(d2) == 23
    assert 0.5 < d2.mean() < 12.0, d2
    assert d2_raw.mean() < 0.1, d2_raw
    # with the motion prior (the default): the uncalibrated file's matches are all drowned by the prior
    # (`prior_dominated`); the calibrated ones far less often. (Not never: at 1.6 m cells a match is
    # coarse beside the prior's few centimetres over a quarter-second step.)
    _, flags = _held_out(onnx, drives["held"], motion_prior=True)
    _, flags_raw = _held_out(raw, drives["held"], motion_prior=True)
    dominated = sum("prior_dominated" in f for f in flags)
    dominated_raw = sum("prior_dominated" in f for f in flags_raw)
    assert dominated_raw == len(flags_raw) - 2 == 21  # every estimate the prior exists for (from the third)
    assert dominated < dominated_raw, (dominated, flags)


def test_train_refuses_a_budget_it_cannot_keep_in_one_line(tmp_path, capsys):
    from radar_odom.commands.cli import main

    for bad in ("-1", "nan"):
        assert main(["train", "-o", str(tmp_path / "m.pt"), "--minutes", bad]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"radar-odom train: error: --minutes {bad}") and "≥ 0" in err[0]
    assert not list(tmp_path.iterdir())


def test_budget_line_names_the_end_time_and_how_to_go_on():
    from radar_odom_export.train import budget_line

    line = budget_line(20.0, now=0.0)
    assert line.startswith("train: 20-minute budget") and "stops by " in line and "--resume continues" in line
    assert "continuing the saved run" in budget_line(5.0, resume=True)
    assert "no time budget" in budget_line(None)


def test_export_calibrates_with_the_calibrate_commands_own_defaults():
    from radar_odom_export.commands import calibrate

    args = calibrate.default_args("m.pt", search="fast", threads=1)
    assert (args.checkpoint, args.search, args.threads, args.sim_seeds, args.covariance) == (
        "m.pt", "fast", 1, "2500", "fitted")
    with pytest.raises(AttributeError, match="no option 'serach'"):
        calibrate.default_args("m.pt", serach="fast")
