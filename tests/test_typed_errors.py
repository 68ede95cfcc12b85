"""Every failure is one typed line (issue 51, item 4, and the small cases beside it): Ray addresses that cannot
be joined, a damaged resume state, the OpenVINO wrapper, the sweep form's loader, the time base's hint and
budgets beyond a week. Each case is fast: the Ray connect timeout is a parameter, given 2 s here, and the
address is checked before Ray is asked anything."""
import importlib.util
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import one_error_line

from radar_odom.commands.cli import main
from radar_odom.errors import ConfigError, InvalidModelError, ModelNotFoundError, RadarOdomError

NO_RAY = importlib.util.find_spec("ray") is None
needs_ray = pytest.mark.skipif(NO_RAY, reason='the fleet extra (Ray) is not installed: pip install -e ".[fleet]"')
NO_TORCH = importlib.util.find_spec("torch") is None



@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("sim") / "drive", seed=4, frames=3, progress=False)


# ------------------------------------------------------------------------------------------------ Ray
@pytest.mark.parametrize("address", ["garbage", "host:text", "host:0", "host:70000", ":6379", "a b:1", "", "local"])
def test_an_address_that_cannot_be_one_is_refused_before_ray_is_asked(address):
    from radar_odom.fleet.scheduler import check_ray_address

    with pytest.raises(ConfigError, match="give 'auto'"):
        check_ray_address(address)


def test_auto_and_host_port_addresses_pass_the_check():
    from radar_odom.fleet.scheduler import check_ray_address

    for address in ("auto", "10.0.0.5:6379", "head-node.cluster.local:6379", "[::1]:6379", "h_1:1"):
        assert check_ray_address(address) == address
    assert check_ray_address(None) is None


@pytest.mark.parametrize("address", ["garbage", "host:text"])
def test_fleet_with_a_garbage_address_is_one_line_at_once(address, drive, tmp_path, capsys):
    t0 = time.perf_counter()
    assert main(["fleet", str(drive), "-o", str(tmp_path / "out"), "--address", address]) == 1
    assert f"--address {address!r}" in one_error_line(capsys, "fleet")
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "out").exists()


@needs_ray
def test_fleet_where_nothing_listens_is_one_line_at_once(drive, cli_model, tmp_path, capsys):
    t0 = time.perf_counter()
    assert main(["fleet", str(drive), "-o", str(tmp_path / "out"), "--address", "127.0.0.1:1", "--model",
                 str(cli_model), "--no-progress"]) == 1
    line = one_error_line(capsys, "fleet")
    assert "--address 127.0.0.1:1: no Ray cluster there (" in line
    assert time.perf_counter() - t0 < 15 and not (tmp_path / "out").exists()


@needs_ray
def test_auto_with_no_cluster_is_one_typed_error(monkeypatch):
    import ray._private.services as services

    from radar_odom.errors import ClusterError
    from radar_odom.fleet.scheduler import ray_connection

    def no_gcs():  # no cluster on this machine, whatever runs on it
        return []

    no_gcs.cache_clear = lambda: None  # as Ray's own (a cached function)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(services, "find_gcs_addresses", no_gcs)
    monkeypatch.setattr(services, "find_bootstrap_address", lambda temp_dir: None)
    with pytest.raises(ClusterError, match=r"--address auto: cannot join the Ray cluster \(ConnectionError: "):
        with ray_connection("auto", timeout_s=5):
            pytest.fail("connected")


@needs_ray
def test_a_port_that_is_no_ray_head_ends_at_the_connect_timeout(tmp_path):
    """A port that accepts connections and never answers as Ray: ray.init alone retries for minutes. In a
    process of its own, since the connect thread given up on is still inside ray.init when it exits."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(8)  # accepted by the kernel, never answered
        port = listener.getsockname()[1]
        code = ("from radar_odom.errors import ClusterError\n"
                "from radar_odom.fleet.scheduler import ray_connection\n"
                "try:\n"
                f"    with ray_connection('127.0.0.1:{port}', timeout_s=2):\n"
                "        print('connected')\n"
                "except ClusterError as exc:\n"
                "    print('ClusterError:', exc)\n")
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        took = time.perf_counter() - t0
    assert f"ClusterError: --address 127.0.0.1:{port}: no Ray cluster answered within 2 s" in done.stdout, done
    assert done.returncode == 0 and took < 60, (took, done.stderr)


@pytest.mark.torch
@pytest.mark.skipif(NO_TORCH, reason="adapt needs the export extra (torch)")
@pytest.mark.parametrize("address, expect", [("garbage", "--address 'garbage': give 'auto'"),
                                             ("127.0.0.1:1", "--address 127.0.0.1:1: no Ray cluster there (")])
def test_adapt_on_ray_with_an_address_it_cannot_join_is_one_line_before_any_work(address, expect, drive, tmp_path,
                                                                                 capsys, monkeypatch):
    if NO_RAY and address != "garbage":
        pytest.skip('the fleet extra (Ray) is not installed: pip install -e ".[fleet]"')
    import radar_odom_export.adapt as adapt_mod

    monkeypatch.setattr(adapt_mod, "read_recording", lambda *a, **k: pytest.fail("read before the check"))
    monkeypatch.setattr(adapt_mod, "base_files", lambda *a, **k: pytest.fail("base prepared before the check"))
    assert main(["adapt", str(drive), "-o", str(tmp_path / "m.onnx"), "--ray", "--address", address]) == 1
    assert expect in one_error_line(capsys, "adapt")


# ------------------------------------------------------------------------------------------ train --resume
@pytest.mark.torch
@pytest.mark.skipif(NO_TORCH, reason="train needs the export extra (torch)")
@pytest.mark.parametrize("damage", ["garbage", "truncated", "no model"])
def test_train_resume_from_a_damaged_state_is_one_line_naming_it_and_keeps_the_best_checkpoint(damage, tmp_path,
                                                                                              capsys):
    import torch

    from radar_odom_export.train import STATE_FORMAT, state_path

    best = tmp_path / "m.pt"
    best.write_bytes(b"the best checkpoint, as it was")
    sp = state_path(best)
    if damage == "garbage":
        sp.write_bytes(b"\x00garbage, not a zip nor a pickle" * 10)
    else:
        state = {"format": STATE_FORMAT, "profile": {}, "objective": "pose", "optimizer": {}, "epoch": 1,
                 "step": 3, "best_val": 1.0, "best_epoch": 1, "history": [], "steps": [], "wall_s": 1.0, "rng": {},
                 "model": {"w": torch.zeros(4096)}}
        if damage == "no model":
            del state["model"]
        torch.save(state, sp)
        if damage == "truncated":  # a disk that filled up while it was written
            sp.write_bytes(sp.read_bytes()[: sp.stat().st_size // 2])
    assert main(["train", "-o", str(best), "--resume", "--minutes", "1"]) == 1
    line = one_error_line(capsys, "train")
    assert f"{sp}: the resume state cannot be read (" in line
    assert "delete it and train again without --resume" in line and f"the best checkpoint {best} is left" in line
    assert best.read_bytes() == b"the best checkpoint, as it was"


@pytest.mark.torch
@pytest.mark.skipif(NO_TORCH, reason="train needs the export extra (torch)")
def test_train_called_with_a_truncated_state_raises_the_same_checkpoint_error(tmp_path):
    from radar_odom.profiles import GridProfile
    from radar_odom_export import data as D
    from radar_odom_export.checkpoint import CheckpointError
    from radar_odom_export.train import TrainConfig, state_path, train

    tiny = GridProfile("tiny", resolution_m=1.6, width_px=64, max_translation_m=4, rotation_range_rad=0.05,
                       rotation_step_rad=0.025, unet_base_channels=4, unet_depth=3)
    state_path(tmp_path / "m.pt").write_bytes(b"PK\x03\x04 truncated")
    cfg = TrainConfig(output=str(tmp_path / "m.pt"), profile=tiny, epochs=1, batch=4, threads=1, resume=True)
    with pytest.raises(CheckpointError, match="m.state.pt: the resume state cannot be read"):
        train(cfg, [D.toy_drive(tiny, 6, 1)], [D.toy_drive(tiny, 6, 2)])


# ------------------------------------------------------------------------------------------ --minutes
@pytest.mark.torch
@pytest.mark.skipif(NO_TORCH, reason="train needs the export extra (torch)")
@pytest.mark.parametrize("minutes", ["1e12", "1e308", "10081"])
def test_train_refuses_a_budget_beyond_a_week_in_one_line(minutes, tmp_path, capsys):
    assert main(["train", "-o", str(tmp_path / "m.pt"), "--minutes", minutes]) == 1
    assert "budgets beyond a week (10080 minutes) are refused" in one_error_line(capsys, "train")
    assert not list(tmp_path.iterdir())


@pytest.mark.torch
@pytest.mark.skipif(NO_TORCH, reason="adapt needs the export extra (torch)")
@pytest.mark.parametrize("minutes", ["1e12", "1e308"])
def test_adapt_refuses_a_budget_beyond_a_week_in_one_line(minutes, drive, tmp_path, capsys, monkeypatch):
    import radar_odom_export.adapt as adapt_mod

    monkeypatch.setattr(adapt_mod, "read_recording", lambda *a, **k: pytest.fail("read before the check"))
    assert main(["adapt", str(drive), "-o", str(tmp_path / "m.onnx"), "--minutes", minutes]) == 1
    assert "budgets beyond a week" in one_error_line(capsys, "adapt")


def test_a_week_is_the_longest_budget():
    from radar_odom.budgets import MAX_BUDGET_MINUTES, check_budget_minutes

    assert check_budget_minutes(MAX_BUDGET_MINUTES) == 10080.0 and check_budget_minutes(0) == 0.0
    for bad in (MAX_BUDGET_MINUTES + 1, float("inf"), float("nan"), -1.0, True, "20"):
        with pytest.raises(ConfigError, match="--minutes"):
            check_budget_minutes(bad)
    with pytest.raises(ConfigError, match="> 0"):
        check_budget_minutes(0, allow_zero=False)


# ------------------------------------------------------------------------------------------ API errors
def test_openvino_config_that_is_no_dict_is_a_config_error(tiny_model):
    from radar_odom.runtimes import OpenVinoModel

    for config in (["f32"], "f32", {1: "x"}):
        with pytest.raises(ConfigError, match="config must be a dict of OpenVINO compile properties"):
            OpenVinoModel(tiny_model, config=config)
    with pytest.raises(ConfigError, match="device"):
        OpenVinoModel(tiny_model, device=0)


def test_openvino_run_with_a_wrong_feed_is_onnxruntimes_typed_error(tiny_model):
    pytest.importorskip("openvino", reason="openvino (the dev extra) is not installed")
    from radar_odom.onnx_model import OnnxModel
    from radar_odom.runtimes import OpenVinoModel

    ort, ov = OnnxModel(tiny_model, threads=1), OpenVinoModel(tiny_model, threads=1)
    names = list(ort.info.inputs)
    wrong_shape = {n: np.zeros((1, 2), np.float32) for n in names}
    for feed in ({"nope": np.zeros(2, np.float32)}, {}, wrong_shape, {names[0]: np.zeros((1, 2), np.float32)}):
        with pytest.raises(InvalidModelError):
            ort.run(feed)
        with pytest.raises(InvalidModelError, match="OpenVINO") as info:
            ov.run(feed)
        assert "\n" not in str(info.value)
    with pytest.raises(InvalidModelError, match="expecting"):  # OpenVINO's reason, its own last line
        ov.run(wrong_shape)


def test_wrapping_a_garbage_file_in_the_sweep_form_is_an_invalid_model_error(tmp_path):
    pytest.importorskip("onnx", reason="onnx (the export extra) builds the sweep form")
    from radar_odom_export.sweep_form import wrap_stream_model

    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x08\x07garbage\xff\xfe not protobuf" * 20)
    with pytest.raises(InvalidModelError, match=r"garbage.onnx: not a readable ONNX model"):
        wrap_stream_model(garbage)
    with pytest.raises(ModelNotFoundError):
        wrap_stream_model(tmp_path / "absent.onnx")
    with pytest.raises(RadarOdomError, match="onnx.ModelProto or a path"):
        wrap_stream_model(b"bytes")


@pytest.mark.parametrize("hint", ["250000", float("nan"), float("inf"), 0, -250000.0, True, [250000]])
def test_a_time_base_hint_that_is_no_period_is_a_config_error(hint):
    from radar_odom.io.timebase import fit_time_base

    stamps = np.arange(40, dtype=np.int64) * 250_000
    with pytest.raises(ConfigError, match="period_hint_us"):
        fit_time_base(stamps, period_hint_us=hint)
    assert fit_time_base(stamps, period_hint_us=np.float64(250000.0)).period_us == pytest.approx(250000.0)
