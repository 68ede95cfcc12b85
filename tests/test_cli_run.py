"""`radar-odom run` and `radar-odom demo` end to end on a tiny simulated drive, and their outputs."""
import numpy as np
import pytest

from radar_odom.commands.cli import main
from radar_odom.evaluation.report import evaluate, format_metrics
from radar_odom.evaluation.trajectory import read_kitti, read_tum
from radar_odom.io import read_sequence
from radar_odom.runs.run_sequence import read_estimates_csv
from radar_odom.se2 import chain_relative

FRAMES = 6


@pytest.fixture(scope="module")
def model_path(cli_model):
    """The committed untrained raw-scan model of the simulator's default sweeps (no torch needed)."""
    return cli_model


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("sim") / "drive", seed=11, frames=FRAMES, progress=False)


def test_run_writes_outputs_and_prints_metrics(model_path, drive, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(drive), "--model", str(model_path), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"{FRAMES} sweeps, {FRAMES - 1} estimates" in printed
    # 6 sweeps are far shorter than a 100 m KITTI segment: per-step errors are printed instead
    assert "too short" in printed and "mean_translation_m" in printed
    for name in ("trajectory.tum", "trajectory.kitti", "estimates.csv", "trajectory.png"):
        assert (out / name).stat().st_size > 0, name
    seq = read_sequence(drive)
    ts, poses = read_tum(out / "trajectory.tum")
    assert np.array_equal(ts, seq.timestamps_us)
    kitti = read_kitti(out / "trajectory.kitti")
    assert kitti.shape == (FRAMES, 3, 3)
    np.testing.assert_allclose(poses, kitti, atol=1e-6)
    est_ts, rel, covs, flags = read_estimates_csv(out / "estimates.csv")
    assert np.array_equal(est_ts, seq.timestamps_us[1:])
    # the files agree with each other: chaining the CSV's relative poses gives the KITTI file
    np.testing.assert_allclose(chain_relative(rel), kitti, atol=1e-6)
    assert np.all(np.isfinite(covs)) and np.allclose(covs, np.transpose(covs, (0, 2, 1)))
    # a raw-scan model on 1.6 m cells still gets the simulated motion to about a cell
    err = rel - seq.gt_relative
    # an untrained model's forward motion is loose, so the motion prior may carry it (flagged)
    assert np.max(np.abs(err[:, :2])) < 1.6 and not any(set(f) - {"prior_dominated"} for f in flags)
    png = (out / "trajectory.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_run_reports_its_pace_with_and_without_the_pipeline(model_path, drive, tmp_path, capsys):
    outs = {}
    for flag in ([], ["--no-pipeline"]):
        out = tmp_path / ("plain" if flag else "pipe")
        assert main(["run", str(drive), "--model", str(model_path), "-o", str(out), "--no-plot", *flag]) == 0
        pace = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("pace (")]
        assert len(pace) == 1 and ("no pipeline" in pace[0]) == bool(flag)
        assert f"{FRAMES} sweeps in" in pace[0] and "sweeps/s" in pace[0] and "decode+parse" in pace[0]
        assert "step" in pace[0] and "wall / max(stages) = " in pace[0]
        outs[out.name] = (out / "estimates.csv").read_bytes(), (out / "trajectory.tum").read_bytes()
    assert outs["pipe"] == outs["plain"]  # the same results either way


def test_run_accepts_a_model_name_and_lists_names_when_unknown(drive, tmp_path, capsys):
    assert main(["run", str(drive), "--model", "no-such-model", "-o", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "no pretrained model 'no-such-model'" in err and "shipped models:" in err


def test_run_without_ground_truth_says_so(model_path, drive, tmp_path, capsys):
    import shutil

    bare = tmp_path / "bare"
    shutil.copytree(drive / "radar", bare / "radar")
    assert main(["run", str(bare), "--model", str(model_path), "-o", str(tmp_path / "o"), "--no-plot"]) == 0
    printed = capsys.readouterr().out
    assert "no ground truth" in printed
    assert not (tmp_path / "o" / "trajectory.png").exists()


def test_evaluate_gives_kitti_metrics_on_a_long_enough_drive():
    # 120 steps of 1.25 m (150 m), estimate 1 % longer. A 150 m drive is scored on segments of
    # 10, 20, …, 80 m (`kitti_lengths_for`). A segment of L m ends at the first frame *beyond* L:
    # L/1.25 + 1 steps = L + 1.25 m, so its error is 0.01 (L + 1.25) m over the nominal L.
    rel = np.tile([1.25, 0.0, 0.0], (120, 1))
    gt = chain_relative(rel)
    est = chain_relative(rel * [1.01, 1.0, 1.0])
    metrics, steps = evaluate(gt, est)
    assert metrics is not None and metrics["step"] == 4 and metrics["pooling"] == "segments"
    assert metrics["lengths_m"] == [10, 20, 30, 40, 50, 60, 70, 80]
    errs, counts = [], []
    for length in metrics["lengths_m"]:
        n = sum(1 for s in range(0, 121, 4) if s + length / 1.25 + 1 <= 120)  # segments that fit
        errs.append(100 * 0.01 * (length + 1.25) / length)
        counts.append(n)
    want = float(np.average(errs, weights=counts))
    assert metrics["translation_percent"] == pytest.approx(want, rel=1e-9)
    assert metrics["num_segments"] == sum(counts)
    assert metrics["rotation_deg_per_m"] == pytest.approx(0.0, abs=1e-9)
    assert steps["mean_translation_m"] == pytest.approx(0.0125)
    text = format_metrics(metrics, steps)
    assert "segments of 10–80 m" in text and "step 4" in text and "pooling segments" in text
    assert f"{want:.3f} %" in text
    short_metrics, _ = evaluate(gt[:20], est[:20])  # 24 m: not even an 80 m segment
    assert short_metrics is None


def test_kitti_lengths_fit_the_drive():
    from radar_odom.evaluation.metrics import KITTI_LENGTHS_M, kitti_lengths_for

    assert kitti_lengths_for(445.0) == (50, 100, 150, 200, 250, 300, 350, 400)
    assert kitti_lengths_for(200.0) == (20, 40, 60, 80, 100, 120, 140, 160)
    assert kitti_lengths_for(900.0) == KITTI_LENGTHS_M == kitti_lengths_for(5000.0)
    assert kitti_lengths_for(88.0) is None and kitti_lengths_for(0.0) is None
    assert kitti_lengths_for(89.0) == (10, 20, 30, 40, 50, 60, 70, 80)


def test_demo_runs_end_to_end_with_a_given_model(model_path, tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--frames", "5", "--model", str(model_path), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "simulated 5 sweeps" in printed and "4 estimates" in printed
    assert (out / "trajectory.png").is_file() and (out / "drive" / "radar").is_dir()


def test_demo_without_shipped_models_is_a_clear_error(tmp_path, capsys, monkeypatch):
    import importlib

    # the module that defines `radar_odom.pretrained`
    pretrained = importlib.import_module("radar_odom.model_zoo")
    monkeypatch.setattr(pretrained, "MODELS_DIR", tmp_path / "none")
    assert main(["demo", "--frames", "3", "-o", str(tmp_path / "d")]) == 1
    assert "ships no pretrained models" in capsys.readouterr().err


# --------------------------------------------------------------------------- bad input (issue 12)
def copy_drive(drive, dest):
    import shutil

    shutil.copytree(drive, dest)
    return dest


def test_run_writes_ground_truth_beside_the_estimate(model_path, drive, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(drive), "--model", str(model_path), "-o", str(out), "--no-plot"]) == 0
    ts_est, _ = read_tum(out / "trajectory.tum")
    ts_gt, gt = read_tum(out / "ground_truth.tum")
    assert np.array_equal(ts_gt, ts_est)  # evo pairs them by time
    seq = read_sequence(drive)
    np.testing.assert_allclose(gt, seq.gt_absolute(), atol=1e-9)
    np.testing.assert_allclose(read_kitti(out / "ground_truth.kitti"), seq.gt_absolute(), atol=1e-9)
    assert "gt_tum: " in capsys.readouterr().out


def test_run_skips_a_corrupt_sweep_bridges_it_and_exits_3(model_path, drive, tmp_path, capsys):
    rec = copy_drive(drive, tmp_path / "rec")
    bad = sorted((rec / "radar").glob("*.png"))[3]
    bad.write_bytes(bad.read_bytes()[:200])  # truncated
    out = tmp_path / "out"
    assert main(["run", str(rec), "--model", str(model_path), "-o", str(out), "--no-plot"]) == 3
    captured = capsys.readouterr()
    assert f"skipped sweep 3 (unreadable): {bad}" in captured.err and "exit status 3" in captured.err
    for name in ("trajectory.tum", "trajectory.kitti", "estimates.csv", "skipped.csv", "ground_truth.tum"):
        assert (out / name).stat().st_size > 0, name
    ts, rel, covs, flags = read_estimates_csv(out / "estimates.csv")
    assert len(ts) == FRAMES - 1 and np.all(np.isfinite(rel))  # one pose per sweep, none lost
    assert {"degenerate", "unreadable"} <= flags[2]  # sweep 3 = estimate 2
    assert "bridged" in flags[3]
    assert covs[2][0, 0] > 1.0  # its covariance says it knows nothing
    assert "metrics" not in captured.out or "per step" in captured.out


def test_run_on_error_stop_writes_what_it_has_and_exits_1(model_path, drive, tmp_path, capsys):
    rec = copy_drive(drive, tmp_path / "rec")
    bad = sorted((rec / "radar").glob("*.png"))[3]
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    out = tmp_path / "out"
    assert main(["run", str(rec), "--model", str(model_path), "-o", str(out), "--no-plot",
                 "--on-error", "stop"]) == 1
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ln.startswith("radar-odom run: error: ")]
    assert len(errors) == 1 and "Traceback" not in err  # (the rest is the progress bar)
    assert "stopped at sweep 3 of 6" in errors[0] and str(bad) in errors[0]
    ts, _ = read_tum(out / "trajectory.tum")
    assert len(ts) == 3


def test_run_reports_bad_models_and_outputs_in_one_line(model_path, drive, tmp_path, capsys):
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(model_path.read_bytes()[:5000])
    assert main(["run", str(drive), "--model", str(corrupt), "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("radar-odom run: error: ") and err.count("\n") == 1 and "corrupt.onnx" in err
    a_file = tmp_path / "taken"
    a_file.write_text("x")
    assert main(["run", str(drive), "--model", str(model_path), "-o", str(a_file)]) == 1
    err = capsys.readouterr().err
    assert "exists and is not a folder" in err and err.count("\n") == 1
    assert main(["run", str(drive), "--model", "../../x", "-o", str(tmp_path / "o")]) == 1
    assert "not a model name" in capsys.readouterr().err


def test_run_warns_about_bad_ground_truth_rows_by_line(model_path, drive, tmp_path, capsys):
    rec = copy_drive(drive, tmp_path / "rec")
    gt = rec / "gt" / "radar_odometry.csv"
    lines = gt.read_text().splitlines()
    parts = lines[2].split(",")
    parts[2] = "nan"
    lines[2] = ",".join(parts)
    gt.write_text("\n".join(lines) + "\n")
    assert main(["run", str(rec), "--model", str(model_path), "-o", str(tmp_path / "o"), "--no-plot"]) == 0
    captured = capsys.readouterr()
    assert "warning:" in captured.err and "line 3" in captured.err
    assert f"1 of {FRAMES - 1} steps lack ground truth" in captured.out


def test_run_help_lists_every_layout_and_bags_and_run_names_its_model(model_path, drive, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for layout in ("Oxford", "Boreas", "MulRan", "RADIATE", "ROS 1 .bag", "--topic", "--bag-out"):
        assert layout in text, layout
    assert main(["run", str(drive), "--model", str(model_path), "-o", str(tmp_path / "o"), "--no-plot"]) == 0
    assert f"model: {model_path}" in capsys.readouterr().out


@pytest.mark.parametrize("threads, match", [
    ("100000", r"--threads=100000 is more than \d+ \(4 per CPU"),  # onnxruntime started them all: a hang
    ("-1", r"--threads must be ≥ 1"), ("two", r"'two' is not a whole number of threads"),
    ("1.5", r"'1.5' is not a whole number of threads"),
])
def test_run_refuses_a_thread_count_it_cannot_use(model_path, drive, tmp_path, capsys, threads, match):
    """--threads 100000 hung the run, -1 was taken without a word: a usage error now, before any work."""
    with pytest.raises(SystemExit) as exit_:
        main(["run", str(drive), "--model", str(model_path), "-o", str(tmp_path / "o"), "--threads", threads])
    assert exit_.value.code == 2
    import re

    assert re.search(match, capsys.readouterr().err)
    assert not (tmp_path / "o").exists()
