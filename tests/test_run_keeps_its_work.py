"""A run never loses its work: every stage after the odometry (the GNSS/INS reference, metrics, plot,
bag) fails into a warning with the reason, the estimates and trajectories are written, exit 0; the
output paths that can be checked are checked before the odometry. And the CLI frictions of the
front door: export names its output by search and refuses to overwrite, --bag-out NAME.mcap is that
file."""
import importlib.util
from types import SimpleNamespace

import pytest
from test_radiate import write_radiate

from radar_odom.commands.cli import main


@pytest.fixture
def radiate_with_gnss(tmp_path, drive):
    """Five RADIATE sweeps (random texture) and a GNSS/INS folder written from the known drive."""
    from test_gnss_ins import write_gnss

    write_radiate(tmp_path)
    write_gnss(tmp_path, drive, until_s=4.0)
    return tmp_path


@pytest.fixture(scope="module")
def drive():
    from test_gnss_ins import make_drive

    return make_drive()


def _run(seq, model, out, *extra):
    return main(["run", str(seq), "--model", str(model), "-o", str(out), "--no-plot", "--no-pipeline", *extra])


@pytest.mark.parametrize("damage", ["garbage time file", "empty time file", "no sample files", "nan samples"])
def test_a_broken_gnss_ins_track_costs_the_metrics_not_the_run(radiate_with_gnss, tiny_model, tmp_path, damage,
                                                               capsys):
    seq = radiate_with_gnss
    times = seq / "GPS_IMU_Twist.txt"
    samples = sorted((seq / "GPS_IMU_Twist").glob("*.txt"))
    if damage == "garbage time file":
        times.write_text("this is not a RADIATE time file\n")
    elif damage == "empty time file":
        times.write_text("")
    elif damage == "no sample files":
        for path in samples:
            path.unlink()
    else:
        for path in samples:
            path.write_text("nan,nan,nan\n")
    out = tmp_path / "out"
    # the tiny model's grid is smaller than a RADIATE sweep: it runs on any sweep that covers it
    assert _run(seq, tiny_model, out) == 0
    text = capsys.readouterr()
    assert "reference: GNSS/INS present but not used" in text.out
    for name in ("trajectory.tum", "trajectory.kitti", "estimates.csv"):
        assert (out / name).is_file()
    assert len((out / "trajectory.tum").read_text().splitlines()) == 5


@pytest.mark.parametrize("offset", ["1e12", "-1e6", "4.5"])
def test_a_clock_offset_off_the_track_leaves_the_reference_unused_and_writes_no_empty_ground_truth(
        radiate_with_gnss, tiny_model, tmp_path, capsys, offset):
    """--gt-time-offset 1e12 gave "5 of 5 steps lack ground truth (see the warnings)" with no warning, and an
    empty ground_truth.tum written and listed: now the reference is not used, and the line says why."""
    out = tmp_path / "out"
    assert _run(radiate_with_gnss, tiny_model, out, f"--gt-time-offset={offset}") == 0
    text = capsys.readouterr()
    assert "reference: GNSS/INS present but not used (the clock offset" in text.out
    assert "radar times outside the GNSS/INS track" in text.out and "lack ground truth" not in text.out
    assert "no metrics: the GNSS/INS reference is not used" in text.out
    assert not (out / "ground_truth.tum").exists() and "gt_tum" not in text.out


def test_a_reused_output_folder_holds_this_runs_outputs_only(radiate_with_gnss, tiny_model, tmp_path, capsys):
    """An earlier run's skipped.csv / ground_truth.tum / ground_truth.kitti / trajectory.png stayed beside the
    new run's outputs in the same -o folder, read as this run's. The run removes its own file names that it did
    not write this time, and nothing else."""
    out = tmp_path / "out"
    out.mkdir()
    stale = ("skipped.csv", "ground_truth.tum", "ground_truth.kitti", "trajectory.png", "estimates.csv")
    for name in stale:
        (out / name).write_text("an earlier run's\n")
    (out / "notes.txt").write_text("mine\n")
    (out / "ground_truth.tum.bak").write_text("mine too\n")
    assert _run(radiate_with_gnss, tiny_model, out, "--gt-time-offset", "1e12") == 1  # refused: earlier outputs
    err = capsys.readouterr().err
    assert "earlier run's outputs" in err and "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert (out / "estimates.csv").read_text() == "an earlier run's\n"  # nothing touched
    assert _run(radiate_with_gnss, tiny_model, out, "--gt-time-offset", "1e12", "--overwrite") == 0
    assert sorted(p.name for p in out.iterdir()) == ["estimates.csv", "ground_truth.tum.bak", "notes.txt",
                                                     "trajectory.kitti", "trajectory.tum"]
    assert (out / "estimates.csv").read_text() != "an earlier run's\n"
    assert "radar-odom run: warning" not in capsys.readouterr().err


def test_an_unwritable_bag_out_is_refused_before_the_odometry(radiate_with_gnss, tiny_model, tmp_path, capsys):
    out = tmp_path / "out"
    assert _run(radiate_with_gnss, tiny_model, out, "--bag-out", str(tmp_path / "missing" / "odom")) == 1
    assert "does not exist" in capsys.readouterr().err
    assert not (out / "trajectory.tum").exists()  # refused before any sweep was matched


def test_a_bag_that_fails_after_the_odometry_is_a_warning(radiate_with_gnss, tiny_model, tmp_path, capsys,
                                                          monkeypatch):
    if importlib.util.find_spec("rosbags") is None:
        pytest.skip("needs rosbags (the ros or dev extra)")
    import radar_odom.runs.run_sequence as run_mod
    from radar_odom.errors import OutputError

    def full_disk(*args, **kwargs):
        raise OutputError("odom: cannot write the bag (No space left on device)")

    monkeypatch.setattr(run_mod, "_write_bag", full_disk)
    out = tmp_path / "out"
    assert _run(radiate_with_gnss, tiny_model, out, "--bag-out", str(tmp_path / "odom")) == 0
    err = capsys.readouterr().err
    assert "warning: --bag-out" in err and "No space left on device" in err
    assert (out / "trajectory.tum").is_file()


# ------------------------------------------------------------------ export's output names
@pytest.fixture
def recorded_exports(monkeypatch):
    pytest.importorskip("torch")
    from radar_odom_export import onnx_export

    asked = []
    monkeypatch.setattr(onnx_export, "export_checkpoint",
                        lambda ckpt, out, **kw: asked.append((str(out), kw)) or SimpleNamespace(summary=lambda: "ok"))
    return asked


def _calibrated_checkpoint(path):
    """A small weightless checkpoint with a calibration record: `export` goes straight to writing."""
    from radar_odom_export.checkpoint import save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    from fixtures import SMALL

    return save_checkpoint(path, MaskedCorrelator(SMALL, masking="raw"), "raw", calibration={"test": "export only"})


@pytest.mark.torch
def test_export_names_its_output_by_search_and_form(recorded_exports, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ckpt = _calibrated_checkpoint(tmp_path / "m.pt")
    for argv in (["cart-0.4"], ["cart-0.4", "--search", "fast", "--form", "sequence"],
                 ["cart-0.4", "--search", "exhaustive"],
                 [str(ckpt)], [str(ckpt), "--search", "exhaustive"], [str(ckpt), "--form", "sequence"]):
        assert main(["export", *argv]) == 0
    names = [out.replace(str(tmp_path) + "/", "") for out, _ in recorded_exports]
    # a user's checkpoint: the fast search is its default, as the shipped models'
    assert names == ["cart-0.4.onnx", "cart-0.4-fast-sequence.onnx", "cart-0.4-exhaustive.onnx", "m.onnx",
                     "m-exhaustive.onnx", "m-fast-sequence.onnx"]
    assert [kw["search"] for _, kw in recorded_exports][3:] == ["fast", "exhaustive", "fast"]


@pytest.mark.torch
def test_export_refuses_to_overwrite_without_force(recorded_exports, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cart-0.4.onnx").write_bytes(b"a model a user made earlier")
    assert main(["export", "cart-0.4"]) == 1
    assert "cart-0.4.onnx exists; pass --force" in capsys.readouterr().err
    assert not recorded_exports
    assert main(["export", "cart-0.4", "--force"]) == 0 and len(recorded_exports) == 1


# ------------------------------------------------------------------ the other front-door frictions
def test_topic_on_a_recording_folder_says_it_is_not_a_bag(radiate_with_gnss, tiny_model, tmp_path, capsys):
    assert _run(radiate_with_gnss, tiny_model, tmp_path / "out", "--topic", "/Navtech/Polar") == 1
    err = capsys.readouterr().err
    assert "--topic /Navtech/Polar applies to ROS bags" in err and "reindex" not in err


def test_a_missing_folder_names_every_layout(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nowhere")]) == 1
    err = capsys.readouterr().err
    for layout in ("radar/*.png", "polar/*.png", "Navtech_Polar/*.png", "ROS bag"):
        assert layout in err, layout


@pytest.mark.parametrize("command", ["profile", "simulate", "run", "export", "calibrate", "demo", "train"])
def test_help_texts_carry_no_empty_defaults(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    assert "(default: None)" not in text and "(default: [])" not in text and "(default: False)" not in text


@pytest.mark.torch
def test_calibrate_defaults_to_the_shipped_search():
    import argparse

    calibrate = pytest.importorskip("radar_odom_export.commands.calibrate", reason="the torch side (radar-odom-export)")
    parser = argparse.ArgumentParser()
    calibrate.register(parser.add_subparsers(dest="command"))
    assert parser.parse_args(["calibrate", "m.pt"]).search == "fast"  # the shipped models' search


def test_defaults_match_what_ships(capsys):
    import argparse

    from radar_odom.commands import demo

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    demo.register(sub)
    with pytest.raises(SystemExit):
        parser.parse_args(["demo", "--scenario", "motorway"])
    assert "invalid choice: 'motorway'" in capsys.readouterr().err


def test_progress_written_to_a_log_is_a_few_whole_lines(capsys):
    """stderr that is not a terminal (a log, CI): whole lines every 20 s and one at the end, never a
    carriage-return redraw per step."""
    pytest.importorskip("tqdm")
    from radar_odom._progress import progress

    bar = progress(total=5000, desc="odometry seq", unit="sweep")
    for _ in range(5000):
        bar.update(1)
    bar.close()
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert 1 <= len(lines) <= 3 and lines[-1].startswith("odometry seq: 100%") and "5000/5000" in lines[-1]


def test_a_duplicate_or_stale_stamp_skips_that_sweep_and_reads_on(cli_model):
    """A bag that re-sends a message (or one stamped earlier) costs that sweep, not the run."""
    from radar_odom import RadarOdometer, iter_estimates
    from radar_odom.sim.simulator import simulate_drive

    scans = [f.scan for f in simulate_drive(3, 5, "urban")]
    stream = scans[:3] + [scans[2], scans[1]] + scans[3:]  # a duplicate, then a stale one
    odo = RadarOdometer(cli_model, threads=1)
    with iter_estimates(stream, odo, prefetch=0) as sweeps:
        got = [(i, ts) for i, ts, _ in sweeps]
    assert [i for i, _ in got] == [0, 1, 2, 5, 6]
    assert [s["reason"] for s in sweeps.skipped] == ["stale_timestamp", "stale_timestamp"]
    assert "is not after the previous sweep's" in sweeps.skipped[0]["message"]
    assert len(odo.trajectory) == 5


def test_a_recording_without_one_usable_sweep_is_an_error_not_an_identity_trajectory(cli_model, tmp_path, capsys):
    from radar_odom.sim.writer import write_drive

    seq = write_drive(tmp_path / "seq", seed=1, frames=3, progress=False)
    for png in (seq / "radar").glob("*.png"):
        png.write_bytes(png.read_bytes()[:100])  # truncated
    assert main(["run", str(seq), "--model", str(cli_model), "-o", str(tmp_path / "out"), "--no-plot"]) == 1
    err = capsys.readouterr().err
    assert "none of its 3 sweeps could be used" in err and "nothing to estimate" in err


def test_a_stamp_jump_no_prediction_can_bridge_starts_a_new_segment(cli_model):
    """A one-hour jump in a bag's stamps was extrapolated by the motion prior (a 24 km step, flagged
    only 'gap'); beyond NEW_SEGMENT_GAP_S the stream starts afresh at the last pose instead."""
    import dataclasses

    import numpy as np

    from radar_odom import RadarOdometer
    from radar_odom.odometry.gaps import NEW_SEGMENT, NEW_SEGMENT_GAP_S
    from radar_odom.sim.simulator import simulate_drive

    scans = [f.scan for f in simulate_drive(4, 6, "urban")]
    hour = 3600 * 10**6
    later = [dataclasses.replace(s, timestamps_us=np.asarray(s.timestamps_us) + hour) for s in scans[3:]]
    odo = RadarOdometer(cli_model, threads=1)
    ests = [odo.step(s) for s in scans[:3] + later]
    assert ests[0] is None and all(NEW_SEGMENT not in e.flags for e in ests[1:3])
    jump = ests[3]
    assert jump.flags == {NEW_SEGMENT} and np.array_equal(jump.pose, np.zeros(3))
    assert all(NEW_SEGMENT not in e.flags and "gap" not in e.flags for e in ests[4:])
    steps = np.hypot(*np.diff(odo.trajectory.poses[:, :2, 2], axis=0).T)
    assert steps.max() < 5.0  # nothing like a 24 km extrapolation
    assert ests[4].pose[0] > 1.0  # the new segment's first pair is a real match again
    assert NEW_SEGMENT_GAP_S == 10.0


def test_a_range_resolution_that_changes_mid_stream_is_an_error(cli_model):
    """Read as given, a sweep with other range bins turned a reader's wrong setting into motion."""
    import dataclasses

    from radar_odom import RadarOdometer
    from radar_odom.errors import StreamError
    from radar_odom.sim.simulator import simulate_drive

    scans = [f.scan for f in simulate_drive(5, 3, "urban")]
    odo = RadarOdometer(cli_model, threads=1)
    odo.step(scans[0])
    odo.step(scans[1])
    wrong = dataclasses.replace(scans[2], range_resolution_m=scans[2].range_resolution_m * 1.1)
    with pytest.raises(StreamError, match=r"range bins of .* but this stream's are .* call reset\(\)"):
        odo.step(wrong)
    odo.reset()
    assert odo.step(wrong) is None  # a new stream takes the new bins


@pytest.mark.torch
def test_train_defaults_to_the_shipped_models_pose_loss():
    pytest.importorskip("torch")
    from radar_odom_export.train import default_pose_loss

    assert default_pose_loss(None) == default_pose_loss("fast") == "ce"  # every shipped model's
    assert default_pose_loss("decoupled") == "mse"  # the one loss the decoupled search takes


@pytest.mark.torch
@pytest.mark.parametrize("where", ["/proc/m.onnx", "/proc/no/such/m.onnx", "folder"])
def test_export_refuses_an_output_it_cannot_write_before_exporting(recorded_exports, tmp_path, monkeypatch, capsys,
                                                                     where):
    """-o /proc/m.onnx raised FileNotFoundError from mkstemp after the whole export (a traceback)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder").mkdir()
    assert main(["export", "cart-0.4", "-o", where, "--force"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "radar-odom export: error:" in err
    assert ("is a folder" in err) if where == "folder" else ("give -o a writable place" in err)
    assert not recorded_exports


@pytest.mark.parametrize("argv, match", [
    (["--frames", "9223372036854775808"], r"frames must be an integer from 1 to 100000"),
    (["--frames", "0"], r"frames must be an integer from 1 to 100000"),
    (["--seed", "-1"], r"seed must be an integer from 0 to"),
    (["--seed", str(2**64)], r"seed must be an integer from 0 to"),
    (["--frames", "2", "AT_A_FILE"], r"exists and is not a folder"),
    (["--frames", "2", "/proc/radar_sim"], r"cannot create the sequence folder"),
])
def test_simulate_refuses_what_it_cannot_write_before_simulating(tmp_path, capsys, argv, match):
    """--frames 2**63 ran until the disk filled; an OUT that is a file, or under /proc, ended in a traceback."""
    (tmp_path / "f").write_text("a file\n")
    out = [a.replace("AT_A_FILE", str(tmp_path / "f")) for a in argv]
    if not any(a.startswith(("/", str(tmp_path))) for a in out):
        out = [str(tmp_path / "sim"), *out]
    assert main(["simulate", *out, "--no-progress"]) == 1
    err = capsys.readouterr().err
    import re

    assert re.search(match, err) and "Traceback" not in err
    assert not (tmp_path / "sim" / "radar").exists()


def test_simulate_refuses_a_drive_the_disk_cannot_hold(tmp_path, capsys, monkeypatch):
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 10**6, 10**6))
    assert main(["simulate", str(tmp_path / "sim"), "--frames", "5", "--no-progress"]) == 1
    assert "5 sweeps take about 0.0 GB (700 kB each) and the disk has 0.0 GB free" in capsys.readouterr().err
    assert not (tmp_path / "sim" / "radar").exists()
