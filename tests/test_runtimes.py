"""Any runtime, checked: the shipped graphs and their sweep form give onnxruntime's poses under OpenVINO's own
runtime (`radar_odom.runtimes.OpenVinoModel`), on onnxruntime's OpenVINO execution provider (runtime
"onnxruntime-openvino": the onnxruntime-openvino wheel, in an environment of its own, .ci/run) and from Node.js
(examples/node on onnxruntime-node), over short simulated recordings, within 1 mm / 1e-4 rad."""
import importlib.util
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import radar_odom
from radar_odom import RadarOdometer, load_scan
from radar_odom.sim import simulate_drive, write_drive

POSE_M, YAW_RAD = 1e-3, 1e-4
NODE_DIR = Path(__file__).resolve().parents[1] / "examples" / "node"


def _assert_same_poses(got, want):
    got, want = np.asarray(got, dtype=np.float64), np.asarray(want, dtype=np.float64)
    assert got.shape == want.shape and len(want) >= 3
    np.testing.assert_allclose(got[:, :2], want[:, :2], atol=POSE_M)
    np.testing.assert_allclose(got[:, 2], want[:, 2], atol=YAW_RAD)
    assert np.abs(want[:, 0]).min() > 1.0  # the drive moves: agreement says something


def _poses(model, scans) -> list:
    # a path gets its session made with threads=1; a loaded model has its own (threads= would be refused)
    odo = RadarOdometer(model, motion_prior=False, **({"threads": 1} if isinstance(model, (str, Path)) else {}))
    return [e.pose for e in (odo.step(s) for s in scans) if e is not None]


@pytest.mark.portability
@pytest.mark.slow
@pytest.mark.parametrize("name", ["cart-0.4", "cart-0.8", "cart-0.4 sweep form"])
def test_openvino_gives_onnxruntimes_poses(name, sweep_form_models):
    pytest.importorskip("openvino", reason="openvino (the dev extra) is not installed")
    from radar_odom.runtimes import OpenVinoModel

    path = sweep_form_models["cart-0.4"] if name.endswith("sweep form") else radar_odom.pretrained(name)
    scans = [f.scan for f in simulate_drive(seed=21, frames=5)]
    # each runtime chains its own states: a difference that grows along the chain shows
    _assert_same_poses(_poses(OpenVinoModel(path, threads=1), scans), _poses(path, scans))


def _needs_openvino_ep():
    """Skips only where neither package that brings onnxruntime's OpenVINO provider is installed."""
    import onnxruntime as ort

    from radar_odom.runtimes import OPENVINO_EP, OPENVINO_EP_PLUGIN

    if OPENVINO_EP not in ort.get_available_providers() and importlib.util.find_spec(OPENVINO_EP_PLUGIN) is None:
        pytest.skip(f"onnxruntime {ort.__version__} has no {OPENVINO_EP}: neither onnxruntime-openvino (an "
                    "onnxruntime of its own: a separate environment, .ci/run) nor onnxruntime-ep-openvino is installed")


@pytest.mark.portability
@pytest.mark.slow
@pytest.mark.parametrize("name", ["cart-0.4", "cart-0.8", "cart-0.4 sweep form", "cart-0.8 sweep form"])
def test_openvino_provider_gives_onnxruntimes_poses(name, sweep_form_models):
    _needs_openvino_ep()
    from radar_odom.runtimes import load_model

    path = sweep_form_models[name.split()[0]] if name.endswith("sweep form") else radar_odom.pretrained(name)
    scans = [f.scan for f in simulate_drive(seed=21, frames=5)]
    # the whole graph on the provider (load_model refuses a split with onnxruntime's CPU provider), its own states
    got = _poses(load_model(path, "onnxruntime-openvino", threads=1), scans)
    _assert_same_poses(got, _poses(path, scans))


def test_openvino_provider_absent_is_one_line_naming_the_package():
    import onnxruntime as ort

    from radar_odom.errors import MissingExtraError
    from radar_odom.runtimes import OPENVINO_EP, OPENVINO_EP_PLUGIN, load_model

    if OPENVINO_EP in ort.get_available_providers() or importlib.util.find_spec(OPENVINO_EP_PLUGIN) is not None:
        pytest.skip("a package bringing onnxruntime's OpenVINO provider is installed here")
    with pytest.raises(MissingExtraError, match="pip install onnxruntime-openvino, in an environment of its own") as e:
        load_model(radar_odom.pretrained("cart-0.4"), "onnxruntime-openvino")
    assert "\n" not in str(e.value)


@pytest.mark.portability
def test_openvino_provider_refuses_a_graph_it_cannot_run_whole(tmp_path):
    """A node the provider leaves to onnxruntime's CPU provider is an error naming the provider, not a silent split:
    the sweep form's 0-d bounds were once a Reshape to the empty shape, which the provider refuses."""
    _needs_openvino_ep()
    pytest.importorskip("onnx", reason="onnx (the export extra) builds the probe graph")
    import onnx
    from onnx import TensorProto, helper

    from radar_odom.errors import InvalidModelError
    from radar_odom.runtimes import load_model

    graph = helper.make_graph(
        [helper.make_node("Reshape", ["x", "empty_shape"], ["x0"]), helper.make_node("Add", ["x0", "x0"], ["y"])],
        "probe", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [])],
        initializer=[helper.make_tensor("empty_shape", TensorProto.INT64, [0], [])])
    path = tmp_path / "split.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8), str(path))
    with pytest.raises(InvalidModelError, match="OpenVINO provider cannot run every node"):
        load_model(path, "onnxruntime-openvino", threads=1)


def _node_ready() -> str | None:
    """Why the Node.js example cannot run here, or None."""
    if shutil.which("node") is None:
        return "node is not on the PATH"
    if not (NODE_DIR / "node_modules" / "onnxruntime-node").is_dir():
        return f"{NODE_DIR}/node_modules is absent: run `npm ci` there (.ci/run does)"
    return None


@pytest.mark.portability
def test_node_program_prints_the_python_sdks_poses(sweep_form_models, tmp_path):
    why = _node_ready()
    if why:
        pytest.skip(why)
    from test_sweep_form import _needs_exact_remap

    _needs_exact_remap()  # held to the SDK path's poses
    write_drive(tmp_path / "drive", seed=23, frames=4)
    files = sorted((tmp_path / "drive" / "radar").glob("*.png"))
    scans = [load_scan(f) for f in files]
    cmd = ["node", str(NODE_DIR / "sweep_odometry.js"), str(sweep_form_models["cart-0.4"]), *map(str, files),
           "--range-resolution-m", repr(scans[0].range_resolution_m)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert [line["sweep"] for line in lines] == [f.name for f in files]
    assert lines[0]["pose"] is None
    # the Python SDK's default path: the shipped stream graph on polar_to_cartesian's image
    _assert_same_poses([line["pose"] for line in lines[1:]], _poses(radar_odom.pretrained("cart-0.4"), scans))


@pytest.mark.portability
@pytest.mark.slow
@pytest.mark.parametrize("runtime", ["openvino", "onnxruntime-openvino"])
def test_profile_times_the_sweep_form_on_openvino(runtime, sweep_form_models):
    if runtime == "openvino":
        pytest.importorskip("openvino", reason="openvino (the dev extra) is not installed")
    else:
        _needs_openvino_ep()
    from radar_odom.latency.sweeps import simulated_pngs
    from radar_odom.latency.timing import profile_model

    r = profile_model(sweep_form_models["cart-0.8"], simulated_pngs(3), steps=3, warmup=1, threads=1,
                      reference_steps=2, operator_steps=5, progress_bar=False, runtime=runtime)
    assert r.stages["graph"]["n"] == 3 and r.stages["graph"]["median"] > 0
    assert not r.operators and any("openvino" in n for n in r.notes)  # onnxruntime's profiler only
    # the graph's poses are the numpy search's on its own masked images (the state chain ran on OpenVINO)
    assert r.reference["same_search"]["pose_diff_median"]["x_m"] < 0.5


@pytest.mark.portability
def test_node_program_times_its_steps(sweep_form_models, tmp_path):
    why = _node_ready()
    if why:
        pytest.skip(why)
    write_drive(tmp_path / "drive", seed=24, frames=2)
    files = [str(f) for f in sorted((tmp_path / "drive" / "radar").glob("*.png"))]
    cmd = ["node", str(NODE_DIR / "sweep_odometry.js"), str(sweep_form_models["cart-0.8"]), *files]
    done = subprocess.run([*cmd, "--time", "3", "--warmup", "1"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    (line,) = [json.loads(s) for s in done.stdout.splitlines()]
    assert line["steps"] == 3 and line["threads"] == 1 and len(line["step_ms"]) == 3
    assert 0 < min(line["step_ms"]) <= line["median_ms"] <= line["p90_ms"] <= max(line["step_ms"])
    bad = subprocess.run([*cmd, "--time", "0.5"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and bad.stderr.startswith("error: usage:") and len(bad.stderr.splitlines()) == 1
