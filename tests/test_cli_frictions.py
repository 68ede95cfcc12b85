"""Every refused command-line case is one line ``radar-odom CMD: error: …`` (issue 42, item 4): no traceback, no
temporary file's name, no empty output folder left behind, refusals before the long work starts."""
import importlib.util
import warnings
import zipfile

import pytest
from conftest import one_error_line
from test_radiate import write_radiate

from radar_odom.commands.cli import main
from radar_odom.errors import StampWarning

HAS_TORCH = all(importlib.util.find_spec(m) is not None for m in ("torch", "radar_odom_export"))
needs_torch = pytest.mark.skipif(not HAS_TORCH, reason="needs torch (the export extra)")



@pytest.fixture
def recording(tmp_path):
    write_radiate(tmp_path / "rec")
    return tmp_path / "rec"


# ---------------------------------------------------------------------------------------------- run
def test_run_given_a_checkpoint_says_to_export_it_first(recording, tmp_path, capsys):
    ckpt = tmp_path / "model.pt"
    with zipfile.ZipFile(ckpt, "w") as z:  # torch.save's format: a zip archive
        z.writestr("model/data.pkl", b"not a graph")
    out = tmp_path / "out"
    assert main(["run", str(recording), "--model", str(ckpt), "-o", str(out), "--no-plot"]) == 1
    line = one_error_line(capsys, "run")
    assert "PyTorch checkpoint" in line and f"radar-odom export {ckpt}" in line and "INVALID_PROTOBUF" not in line
    assert not out.exists()  # the refused run left no empty folder


def test_a_zip_under_another_name_is_still_a_checkpoint(tmp_path):
    from radar_odom.onnx_model import is_torch_checkpoint

    weights = tmp_path / "weights.bin"
    with zipfile.ZipFile(weights, "w") as z:
        z.writestr("a", b"b")
    (tmp_path / "model.onnx").write_bytes(b"\x08\x07\x12\x05torch")  # a protobuf starts otherwise
    assert is_torch_checkpoint(weights) and is_torch_checkpoint(tmp_path / "m.pth")
    assert not is_torch_checkpoint(tmp_path / "model.onnx") and not is_torch_checkpoint(tmp_path / "missing")


def test_run_refuses_a_folder_of_earlier_outputs_unless_overwrite(recording, tiny_model, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["run", str(recording), "--model", str(tiny_model), "-o", str(out), "--no-plot", "--no-pipeline"]
    assert main(args) == 0
    first = (out / "estimates.csv").read_text()
    capsys.readouterr()
    assert main(args) == 1
    line = one_error_line(capsys, "run")
    assert "estimates.csv" in line and "--overwrite" in line
    assert main([*args, "--overwrite"]) == 0
    assert (out / "estimates.csv").read_text() == first  # same run, same result: the folder was reused
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine\n")  # a folder of other things is no earlier run
    assert main([*args[:5], str(other), *args[6:]]) == 0


def test_a_missing_bag_is_said_not_to_exist(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "drive.mcap"), "--topic", "/radar", "-o", str(out)]) == 1
    line = one_error_line(capsys, "run")
    assert "drive.mcap: does not exist" in line and "is not one" not in line
    assert not out.exists()


def test_run_without_rosbags_for_bag_out_leaves_no_folder(recording, tiny_model, tmp_path, capsys, monkeypatch):
    import radar_odom.io.bag_out as bag_out
    from radar_odom.errors import MissingExtraError

    def no_rosbags():
        raise MissingExtraError("rosbags", "ros")

    monkeypatch.setattr(bag_out, "_rosbags_writer", no_rosbags)
    out = tmp_path / "deep" / "out"
    assert main(["run", str(recording), "--model", str(tiny_model), "-o", str(out), "--bag-out",
                 str(tmp_path / "odom")]) == 1
    assert "rosbags" in one_error_line(capsys, "run")
    assert not out.exists()


def test_a_run_failing_inside_leaves_no_empty_folder_but_keeps_an_existing_one(recording, tiny_model, tmp_path,
                                                                                 capsys, monkeypatch):
    import radar_odom.runs.run_sequence as run_mod
    from radar_odom.errors import ModelMismatchError

    def mismatch(*args, **kwargs):
        raise ModelMismatchError("the model does not fit this radar")

    monkeypatch.setattr(run_mod, "_run", mismatch)
    out = tmp_path / "new"
    assert main(["run", str(recording), "--model", str(tiny_model), "-o", str(out)]) == 1
    one_error_line(capsys, "run")
    assert not out.exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    assert main(["run", str(recording), "--model", str(tiny_model), "-o", str(mine)]) == 1
    assert mine.is_dir()  # the user's own (empty) folder is not ours to remove


def test_demo_that_fails_leaves_no_empty_folder(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--model", str(tmp_path / "missing.onnx"), "-o", str(out), "--frames", "4"]) == 1
    assert "no such model file" in one_error_line(capsys, "demo")
    assert not out.exists()


def test_keep_stamps_reaches_the_reader(recording, tmp_path, monkeypatch):
    import radar_odom.runs.run_sequence as run_mod

    seen = {}

    def fake_run_sequence(*args, **kwargs):
        seen.update(kwargs)
        raise run_mod.ConfigError("stop here")

    monkeypatch.setattr(run_mod, "run_sequence", fake_run_sequence)
    main(["run", str(recording), "-o", str(tmp_path / "a")])
    assert seen["repair_stamps"] is True
    main(["run", str(recording), "-o", str(tmp_path / "b"), "--keep-stamps"])
    assert seen["repair_stamps"] is False


def test_the_stamp_warning_names_the_cli_option(tmp_path):
    """RADIATE stamps a host stamped late are put back; the warning says how to keep them, for the CLI too."""
    times = [f"{1574859771.0 + 0.25 * k + (0.12 if k == 6 else 0.0):.6f}" for k in range(12)]
    write_radiate(tmp_path, frames=tuple(range(1, 13)), times=times)
    from radar_odom import read_sequence

    with pytest.warns(StampWarning, match="--keep-stamps"):
        read_sequence(tmp_path)


def test_threads_zero_is_refused_in_cli_words(capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["run", str(tmp_path), "--threads", "0"])
    err = capsys.readouterr().err
    assert "--threads must be ≥ 1" in err and "None" not in err


# ------------------------------------------------------------------------------------------ profile
@pytest.mark.parametrize("flag, value", [("--steps", "0"), ("--warmup", "-1"), ("--rss-steps", "-5")])
def test_profile_refuses_counts_it_cannot_use(flag, value, tmp_path, capsys):
    out = tmp_path / "prof"
    assert main(["profile", flag, value, "-o", str(out), "--no-progress"]) == 1
    line = one_error_line(capsys, "profile")
    assert f"{flag} must be a whole number" in line and value in line
    assert not out.exists()


# ------------------------------------------------------------------------------------------- export
@pytest.mark.torch
@needs_torch
@pytest.mark.parametrize("opset", ["5", "17", "1000"])
def test_export_refuses_an_opset_it_cannot_reach_before_tracing(opset, tmp_path, capsys):
    out = tmp_path / "m.onnx"
    assert main(["export", "cart-0.8", "--opset", opset, "-o", str(out)]) == 1
    line = one_error_line(capsys, "export")
    assert f"--opset {opset}" in line and "{got}" not in line and ".partial" not in line
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.torch
@needs_torch
def test_export_fast_search_on_a_yaw_step_that_does_not_divide_the_turn_is_one_line(tmp_path, capsys):
    """A user's profile with a yaw step of 0.7° (514.3 steps a turn) and --search fast: one line that
    says why and what to do, before any tracing (was: a raw ValueError from the polar rotation)."""
    import math

    from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint, write_checkpoint_dict

    ckpt = read_checkpoint_dict(resolve_checkpoint("cart-0.8"))
    odd = {**ckpt, "profile": {**ckpt["profile"], "rotation_step_rad": math.radians(0.7)}}
    path = write_checkpoint_dict(tmp_path / "odd.pt", odd)
    out = tmp_path / "odd.onnx"
    assert main(["export", str(path), "--search", "fast", "-o", str(out)]) == 1
    line = one_error_line(capsys, "export")
    assert "0.7°" in line and "does not divide 360°" in line and "--search exhaustive" in line
    assert not out.exists()


@pytest.mark.torch
@needs_torch
def test_the_opset_check_names_the_file_asked_for(tmp_path):
    """The check after writing names the output and the opset it got (was: the temporary file and `{got}`)."""
    import onnx
    from onnx import TensorProto, helper

    from radar_odom.errors import ExportError
    from radar_odom_export.onnx_export import check_onnx_file

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    path = tmp_path / "m.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)]), str(path))
    with pytest.raises(ExportError, match=r"choose --opset 18 ") as info:
        check_onnx_file(path, opset=17)
    assert "{got}" not in str(info.value)


# -------------------------------------------------------------------------------------------- adapt
@pytest.mark.torch
@needs_torch
@pytest.mark.parametrize("extra, expect", [
    (["--real-fraction", "2"], "--real-fraction is a share"),
    (["--lr", "nan"], "--lr must be a positive number"),
    (["--holdout", "1"], "--holdout is a share"),
    (["--max-skip", "0"], "--max-skip must be a whole number ≥ 1"),
    (["--minutes", "inf"], "--minutes must be a positive number"),
    (["--resume"], "--resume: no interrupted run"),
])
def test_adapt_refuses_settings_before_reading_the_recording(extra, expect, recording, tmp_path, capsys,
                                                             monkeypatch):
    import radar_odom_export.adapt as adapt_mod

    def never(*args, **kwargs):
        raise AssertionError("the recording was read before the settings were checked")

    monkeypatch.setattr(adapt_mod, "read_recording", never)
    monkeypatch.setattr(adapt_mod, "base_files", never)
    assert main(["adapt", str(recording), "-o", str(tmp_path / "m.onnx"), *extra]) == 1
    assert expect in one_error_line(capsys, "adapt")


@pytest.mark.torch
@needs_torch
@pytest.mark.parametrize("where", ["under a file", "/proc"])
def test_adapt_refuses_an_output_it_cannot_write(where, recording, tmp_path, capsys, monkeypatch):
    import radar_odom_export.adapt as adapt_mod

    monkeypatch.setattr(adapt_mod, "read_recording", lambda *a, **k: pytest.fail("read before the check"))
    if where == "/proc":
        out = "/proc/m.onnx"
    else:
        (tmp_path / "a-file").write_text("x")
        out = str(tmp_path / "a-file" / "m.onnx")
    assert main(["adapt", str(recording), "-o", out]) == 1
    assert "give -o a writable place" in one_error_line(capsys, "adapt")


def test_warnings_under_a_long_command_print_in_cli_words(capsys):
    from radar_odom.commands import cli_warnings

    with cli_warnings("adapt"):
        warnings.warn("12 sweep stamps were late; to keep them as recorded, ... (radar-odom run --keep-stamps)",
                      StampWarning, stacklevel=1)
    err = capsys.readouterr().err
    assert err.strip() == ("radar-odom adapt: warning: 12 sweep stamps were late; to keep them as recorded, ... "
                           "(radar-odom run --keep-stamps)")
    assert "StampWarning" not in err and "warnings.warn" not in err


@pytest.mark.torch
def test_export_refuses_no_calibrate_with_calibration_data_before_any_work(tmp_path, capsys):
    """Issue 51: `export --no-calibrate --calibration-data X` dropped the data without a word."""
    pytest.importorskip("torch", reason="export needs the export extra (torch)")
    out = tmp_path / "m.onnx"
    assert main(["export", "cart-0.8", "-o", str(out), "--no-calibrate", "--calibration-data", str(tmp_path)]) == 1
    assert "contradict" in one_error_line(capsys, "export") and not out.exists()
