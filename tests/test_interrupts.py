"""Ctrl-C and SIGTERM keep the work (issue 51, item 2): `radar-odom run` interrupted mid-recording writes the
outputs so far, marked partial as ``--on-error stop`` marks them (partial.txt), says at which sweep in one line and
exits 130 (SIGINT) / 143 (SIGTERM); fleet, train and adapt keep what they had done for the same command again.

`run` is interrupted for real: a subprocess whose steps are slowed and announced, signalled mid-recording (SIGINT
to its process group, as a terminal's Ctrl-C; SIGTERM to the process, as a service manager). fleet (a local Ray
takes ~10 s to start here), train and adapt are interrupted in this process by a real signal sent to it at a known
point of their work (`os.kill`), through the command line's own handling (`radar_odom.commands.cli.main`)."""
import csv
import os
import re
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from radar_odom.commands.cli import main
from radar_odom.commands.interrupts import (
    SIGINT_STATUS,
    SIGTERM_STATUS,
    Terminated,
    exit_status,
    interrupted_line,
    sigterm_interrupts,
)
from radar_odom.errors import RunInterrupted
from radar_odom.evaluation.trajectory import read_tum
from radar_odom.runs.run_sequence import PARTIAL_FILE, read_estimates_csv

FRAMES = 8
SIGNALS = {"SIGINT": (signal.SIGINT, SIGINT_STATUS), "SIGTERM": (signal.SIGTERM, SIGTERM_STATUS)}

# `radar-odom run` with every step slowed and announced on stdout: the test's clock, the real command line
DRIVER = textwrap.dedent("""
    import signal, sys, time
    from radar_odom.commands.cli import main
    from radar_odom.odometry.odometer import RadarOdometer

    # as a command started in a terminal: a child of a non-interactive shell's background job inherits SIGINT ignored
    signal.signal(signal.SIGINT, signal.default_int_handler)

    step, steps = RadarOdometer.step, [0]

    def announced(self, scan, *args, **kwargs):
        out = step(self, scan, *args, **kwargs)
        steps[0] += 1
        print(f"stepped {steps[0]}", flush=True)
        time.sleep(0.2)
        return out

    RadarOdometer.step = announced
    sys.exit(main(sys.argv[1:]))
""")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("interrupts") / "rec", seed=11, frames=FRAMES, progress=False)


def _one_line(err: str, command: str) -> str:
    """The command's own line on stderr, checked to be the only one (the rest is progress), with no traceback."""
    assert "Traceback" not in err, err
    ours = [ln for ln in err.splitlines() if ln.startswith(f"radar-odom {command}:")]
    assert len(ours) == 1, err
    return ours[0]


def _check_partial(out, upto: int):
    """``out`` holds the outputs of the first ``upto`` sweeps, consistent with each other, marked partial."""
    ts, poses = read_tum(out / "trajectory.tum")
    est_ts, rel, _, _ = read_estimates_csv(out / "estimates.csv")
    assert len(ts) == upto and len(est_ts) == max(upto - 1, 0)
    assert np.array_equal(est_ts, ts[1:]) and np.all(np.isfinite(poses))
    assert len((out / "trajectory.kitti").read_text().splitlines()) == upto
    marker = (out / PARTIAL_FILE).read_text()
    assert marker.startswith("partial: ") and f"the first {upto} of the recording's {FRAMES} sweeps" in marker
    assert not (out / "ground_truth.tum").exists() and not (out / "ground_truth.kitti").exists()


# ------------------------------------------------------------------ radar-odom run, for real
@pytest.mark.parametrize("name", sorted(SIGNALS))
def test_an_interrupted_run_writes_the_outputs_so_far_marked_partial(recording, cli_model, tmp_path, name):
    """Ctrl-C at sweep 86 of 100 printed `interrupted`, exited 130 and wrote nothing; SIGTERM killed the run
    without a word. Now both keep the sweeps so far, in one line, and the same command with --overwrite redoes it."""
    sig, status = SIGNALS[name]
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER)
    out = tmp_path / "out"
    argv = ["run", str(recording), "--model", str(cli_model), "-o", str(out), "--no-plot"]
    proc = subprocess.Popen([sys.executable, str(driver), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    try:
        for line in proc.stdout:
            if line.startswith("stepped 3"):  # mid-recording: the third step is done, the fourth not begun
                if sig == signal.SIGINT:
                    os.killpg(proc.pid, sig)  # a terminal's Ctrl-C: the whole process group
                else:
                    proc.send_signal(sig)
                break
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, err
    line = _one_line(err, "run")
    said = re.fullmatch(rf"radar-odom run: interrupted \({name}\) at sweep (\d+) of {FRAMES}: the outputs for "
                        rf"the (\d+) sweeps before it are written to {re.escape(str(out))}, marked partial "
                        rf"\({PARTIAL_FILE}; no metrics or ground truth\); the same command with --overwrite runs "
                        r"the whole recording again", line)
    assert said, line
    at, kept = int(said[1]), int(said[2])
    assert at == kept and 2 <= kept < FRAMES  # the step in hand when the signal came: its pose is not written
    _check_partial(out, kept)
    assert f"interrupted at sweep {at} of {FRAMES}" in (out / PARTIAL_FILE).read_text()
    # the same command refuses to overwrite the partial outputs in silence; with --overwrite it does the whole
    assert main(argv) == 1
    assert main([*argv, "--overwrite"]) == 0
    assert not (out / PARTIAL_FILE).exists() and (out / "ground_truth.tum").is_file()
    assert len(read_tum(out / "trajectory.tum")[0]) == FRAMES


# ------------------------------------------------------------------ run_sequence, the library
def test_an_interrupt_inside_a_step_leaves_outputs_that_agree_with_each_other(recording, cli_model, tmp_path,
                                                                            monkeypatch):
    """Python raises Ctrl-C between any two bytecodes: here after the odometer appended sweep 4's pose but before
    its estimate reached the run. The outputs are those of the three sweeps before it, every file agreeing."""
    from radar_odom.odometry.odometer import RadarOdometer
    from radar_odom.runs.run_sequence import run_sequence

    step, calls = RadarOdometer.step, []

    def interrupted_in_the_fourth(self, scan, *args, **kwargs):
        out = step(self, scan, *args, **kwargs)
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return out

    monkeypatch.setattr(RadarOdometer, "step", interrupted_in_the_fourth)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt) as raised:  # still a KeyboardInterrupt for a library caller
        run_sequence(recording, cli_model, out, plot=False, show_progress=False)
    exc = raised.value
    assert isinstance(exc, RunInterrupted) and isinstance(exc.cause, KeyboardInterrupt)
    assert str(exc).startswith(f"interrupted at sweep 3 of {FRAMES}: the outputs for the 3 sweeps before it")
    assert len(exc.result.timestamps_us) == 3 and len(exc.result.estimates) == 2 and exc.result.metrics is None
    assert exc.result.files["partial"] == out / PARTIAL_FILE
    _check_partial(out, 3)


def test_on_error_stop_marks_its_outputs_partial_the_same_way(recording, cli_model, tmp_path, capsys):
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(recording, rec)
    sorted((rec / "radar").glob("*.png"))[5].write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    out = tmp_path / "out"
    assert main(["run", str(rec), "--model", str(cli_model), "-o", str(out), "--no-plot", "--on-error", "stop"]) == 1
    line = _one_line(capsys.readouterr().err, "run")
    assert "stopped at sweep 5 of 8" in line and f"marked partial ({PARTIAL_FILE})" in line
    _check_partial(out, 5)
    assert "stopped at sweep 5 of 8 (on_error='stop')" in (out / PARTIAL_FILE).read_text()


# ------------------------------------------------------------------ the command line's SIGTERM
def test_sigterm_raises_terminated_within_a_command_and_the_old_handler_comes_back():
    def before(signum, frame):
        raise AssertionError("the previous handler ran inside the block")

    old = signal.signal(signal.SIGTERM, before)
    try:
        with pytest.raises(Terminated) as raised:
            with sigterm_interrupts():
                _signal_self(signal.SIGTERM)
        assert isinstance(raised.value, KeyboardInterrupt)  # finally blocks and `except KeyboardInterrupt` run
        assert signal.getsignal(signal.SIGTERM) is before
    finally:
        signal.signal(signal.SIGTERM, old)
    assert exit_status(raised.value) == 143 and exit_status(KeyboardInterrupt()) == 130
    wrapped = RunInterrupted("interrupted at sweep 4 of 9: the outputs ...", None, raised.value)
    assert interrupted_line("run", wrapped, "hint") == ("radar-odom run: interrupted (SIGTERM) at sweep 4 of 9: the "
                                                        "outputs ...; hint")
    assert interrupted_line("fleet", KeyboardInterrupt()) == "radar-odom fleet: interrupted (SIGINT)"


def test_a_local_ray_keeps_the_command_lines_sigterm_handler():
    """ray.init on the main thread sets SIGTERM to sys.exit(15): fleet under SIGTERM then ended with status 15
    and no line. The command line's handler is put back; without one, Ray's stays as before."""
    import types

    from radar_odom.fleet.scheduler import connect_ray

    def ray_exit(signum, frame):  # what ray.init installs
        sys.exit(signum)

    fake = types.SimpleNamespace(init=lambda **kwargs: signal.signal(signal.SIGTERM, ray_exit))
    old = signal.getsignal(signal.SIGTERM)
    try:
        with sigterm_interrupts():
            ours = signal.getsignal(signal.SIGTERM)
            connect_ray(fake, None)
            assert signal.getsignal(signal.SIGTERM) is ours
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        connect_ray(fake, None)
        assert signal.getsignal(signal.SIGTERM) is ray_exit
    finally:
        signal.signal(signal.SIGTERM, old)


@pytest.fixture(autouse=True)
def python_ctrl_c():
    """Python's own Ctrl-C handler for the in-process signals: a process started in the background by a
    non-interactive shell (a CI script) inherits SIGINT ignored, and then no KeyboardInterrupt comes."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _signal_self(sig):
    """A real signal to this process, mid-work: POSIX delivers it to this thread before `os.kill` returns, so the
    handler raises at once; the sleep only bounds the wait if it did not."""
    os.kill(os.getpid(), sig)
    time.sleep(1.0)


# ------------------------------------------------------------------ fleet
@pytest.mark.skipif(__import__("importlib").util.find_spec("ray") is None, reason="needs ray (the fleet extra)")
@pytest.mark.parametrize("name", sorted(SIGNALS))
def test_an_interrupted_fleet_keeps_the_recordings_done_and_the_same_command_runs_the_rest(
        recording, cli_model, tmp_path, monkeypatch, capsys, name):
    """Ray's own start is ~10 s here: the recordings run one after the other in this process instead (the job
    each Ray worker runs, `process_recording`), and the signal comes after the first is published."""
    import shutil

    from radar_odom.fleet import scheduler
    from radar_odom.fleet.job import process_recording
    from radar_odom.fleet.manifest import MANIFEST
    from radar_odom.fleet.report import DONE, KEPT

    sig, status = SIGNALS[name]
    recs = [tmp_path / "van1", tmp_path / "van2"]
    for r in recs:
        shutil.copytree(recording, r)
    interrupt = [True]

    def one_by_one(run, pending, recordings, names, keys, out_dir, model_path, options, *rest):
        out_dir.mkdir(parents=True, exist_ok=True)
        for i in pending:
            run.rows[i] = {**process_recording(model_path, recordings[i], out_dir, names[i], options, keys[i]),
                           "attempts": 1}
            if interrupt[0]:
                _signal_self(sig)

    monkeypatch.setattr(scheduler, "_run_on_ray", one_by_one)
    out = tmp_path / "out"
    argv = ["fleet", *map(str, recs), "-o", str(out), "--model", str(cli_model), "--no-plot", "--no-progress"]
    assert main(argv) == status
    line = _one_line(capsys.readouterr().err, "fleet")
    assert line == (f"radar-odom fleet: interrupted ({name}); 1 of 2 recordings are done and kept in {out} (each "
                    "written whole); the same command again runs only the others and writes the report")
    assert (out / "van1" / MANIFEST).is_file() and not (out / "van2").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".van")]  # no half-written folder left
    interrupt[0] = False
    assert main(argv) == 0
    with open(out / "fleet.csv", newline="") as f:
        status_of = {r["recording"]: r["status"] for r in csv.DictReader(f)}
    assert status_of == {"van1": KEPT, "van2": DONE}


# ------------------------------------------------------------------ train and adapt
@pytest.fixture
def train_data(tmp_path, monkeypatch):
    pytest.importorskip("torch")
    import json
    from dataclasses import asdict

    from radar_odom.profiles import GridProfile
    from radar_odom.sim import SimConfig, write_drive

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    cfg = SimConfig().with_sensor(num_bins=800)  # 35 m of range: small files, fast
    recs = [write_drive(tmp_path / f"seq{s}", seed=s, frames=5, config=cfg, progress=False) for s in (41, 42)]
    tiny = GridProfile("tiny", resolution_m=1.6, width_px=64, max_translation_m=4, rotation_range_rad=0.05,
                       rotation_step_rad=0.025, unet_base_channels=4, unet_depth=3)
    prof = tmp_path / "tiny.json"
    prof.write_text(json.dumps(asdict(tiny)))
    return recs, prof


@pytest.mark.torch
@pytest.mark.parametrize("name", sorted(SIGNALS))
def test_an_interrupted_train_resumes_from_its_last_saved_epoch(train_data, tmp_path, monkeypatch, capsys, name):
    import json

    from radar_odom_export import train as train_mod

    sig, status = SIGNALS[name]
    recs, prof = train_data
    out = tmp_path / "m.pt"
    argv = ["train", *map(str, recs), "-o", str(out), "--profile", str(prof), "--epochs", "3", "--batch", "2",
            "--threads", "1", "--minutes", "0"]
    save, interrupt = train_mod._save_state, [True]

    def saved_then_signalled(cfg, model, optim, epoch, *args):
        save(cfg, model, optim, epoch, *args)
        if interrupt[0] and epoch == 1:  # mid-run: epoch 1 saved, two to go
            _signal_self(sig)

    monkeypatch.setattr(train_mod, "_save_state", saved_then_signalled)
    assert main(argv) == status
    line = _one_line(capsys.readouterr().err, "train")
    assert line == (f"radar-odom train: interrupted ({name}); m.state.pt holds epoch 1: the same command with "
                    "--resume continues from there; the steps since are lost")
    interrupt[0] = False
    assert main([*argv, "--resume"]) == 0
    epochs = json.loads(train_mod.log_path(out).read_text())["epochs"]
    assert [e["epoch"] for e in epochs] == [1, 2, 3]


@pytest.mark.torch
def test_an_interrupted_adapt_says_whether_resume_can_continue(tmp_path, monkeypatch, capsys, recording):
    """adapt's interruptible work is its training (`train`, above, saves each epoch for --resume); what adapt
    adds is the line: --resume where its training saved an epoch, starting over where none had ended."""
    torch = pytest.importorskip("torch")
    from radar_odom_export import adapt as adapt_mod
    from radar_odom_export.train import STATE_FORMAT, STATE_KEYS, state_path

    out = tmp_path / "mine.onnx"
    saves = []

    def signalled(recordings, output, cfg, **kwargs):
        for state in saves:  # what an epoch of its training writes
            torch.save({"format": STATE_FORMAT, **dict.fromkeys(STATE_KEYS, 0), "epoch": 2}, state_path(state))
        _signal_self(signal.SIGTERM)

    monkeypatch.setattr(adapt_mod, "adapt", signalled)
    argv = ["adapt", str(recording), "-o", str(out)]
    assert main(argv) == SIGTERM_STATUS
    assert _one_line(capsys.readouterr().err, "adapt") == (
        "radar-odom adapt: interrupted (SIGTERM); no epoch had ended, so nothing is saved to resume: the same "
        "command again starts over")
    saves.append(out.with_suffix(".pt"))
    assert main(argv) == SIGTERM_STATUS
    assert _one_line(capsys.readouterr().err, "adapt") == (
        "radar-odom adapt: interrupted (SIGTERM); mine.state.pt holds epoch 2: the same command with --resume "
        "continues from there (the recordings are read and labelled again first); the steps since are lost")


@pytest.mark.torch
def test_build_drives_workers_leave_ctrl_c_to_the_parent():
    """A terminal's Ctrl-C reaches train's simulation workers too: each printed its own KeyboardInterrupt
    traceback. They ignore it; the parent stops the pool."""
    pytest.importorskip("torch")
    from radar_odom_export import data

    old = signal.getsignal(signal.SIGINT)
    try:
        data._ignore_ctrl_c()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old)
