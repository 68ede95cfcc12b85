"""int8 masker (`radar_odom_export.quantize`): QDQ around the U-Net's Conv nodes only, calibrated on
simulated sweeps, checked and verified against the float32 file, recorded in the metadata.

Works on the committed `small-fast-learned.onnx` fixture (a seeded U-Net masker and the fast
search); export-side (the file checks are `onnx_export`'s, which imports torch)."""
from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime.quantization")

from radar_odom.errors import ExportError, InvalidModelError  # noqa: E402
from radar_odom.model_file import ModelInfo  # noqa: E402
from radar_odom.onnx_model import OnnxModel  # noqa: E402
from radar_odom.polar import polar_to_cartesian  # noqa: E402
from radar_odom.sim import simulate_drive  # noqa: E402
from radar_odom_export.quantize import (  # noqa: E402
    QUANTIZE_CHOICES,
    REAL_HOLDOUT,
    SCHEME,
    Int8Tolerance,
    check_qdq_conv_only,
    quantize_model,
    quantize_scheme,
    real_calibration_drives,
    stream_feeds,
)

QDQ = {"QuantizeLinear", "DequantizeLinear"}


def sweeps(info, seed: int, frames: int, scenario: str) -> np.ndarray:
    """float32[F, W, W]: a simulated drive on the model's grid, as `RadarOdometer` converts scans
    (test seeds 0-99, the policy's range for tests)."""
    p = info.profile
    return np.stack([polar_to_cartesian(f.scan, p.resolution_m, p.width_px, near_range_m=p.near_range_m)
                     for f in simulate_drive(seed, frames, scenario)]).astype(np.float32)


@pytest.fixture(scope="module")
def drives(fast_learned_model):
    info = OnnxModel(fast_learned_model, threads=1).info
    calib = [sweeps(info, 0, 10, "urban"), sweeps(info, 1, 10, "open")]
    check = [sweeps(info, 2, 10, "heavy_traffic")]
    return calib, check


@pytest.fixture(scope="module")
def quantised(fast_learned_model, drives, tmp_path_factory):
    calib, check = drives
    out = tmp_path_factory.mktemp("q") / "small-int8.onnx"
    report = quantize_model(fast_learned_model, out, drives=calib, verify_drives=check, calibration_every=1,
                            calibration={"seeds": [0, 1]}, exclude="")  # every Conv, the strictest check
    return out, report


def ops(path) -> Counter:
    return Counter(n.op_type for n in onnx.load(str(path)).graph.node)


def test_quantised_graph_runs_and_records_it(quantised, fast_learned_model):
    out, report = quantised
    m = OnnxModel(out, threads=1)  # loads as the runtime loads it: metadata, signature
    q = m.info.quantization
    assert q == report.quantization and json.loads(json.dumps(q)) == q
    assert q["scheme"] == "static" and q["format"] == "qdq"
    assert q["op_types"] == ["Conv"] and q["weight_type"] == "int8" and q["per_channel"] is True
    assert q["calibration"]["sweeps"] == 18 and q["calibration"]["seeds"] == [0, 1]
    assert OnnxModel(fast_learned_model, threads=1).info.quantization is None
    x = np.zeros(m.info.input_shape, np.float32)
    out_ = m.run({"cart": x, "prev_state": np.zeros(m.info.state_shape, np.float32)})
    assert out_["pose"].shape[-1] == 3 and np.all(np.isfinite(out_["pose"]))
    # everything but the quantised masker is the float32 file's: same metadata otherwise
    base = dict(OnnxModel(fast_learned_model).session.get_modelmeta().custom_metadata_map)
    mine = dict(m.session.get_modelmeta().custom_metadata_map)
    assert {k: v for k, v in mine.items() if k != "radar_odom.quantization"} == base


def test_qdq_around_conv_only(quantised, fast_learned_model):
    out, report = quantised
    before, after = ops(fast_learned_model), ops(out)
    assert before["Conv"] == after["Conv"] == report.conv_nodes > 0
    assert sum(after[o] for o in QDQ) == report.qdq_nodes > 0
    # nothing else changed: the correlation, DFT matmuls, rotation and soft-argmax stay float32
    assert {k: v for k, v in after.items() if k not in QDQ} == dict(before)
    proto = onnx.load(str(out))
    check_qdq_conv_only(proto)
    producer = {o: n for n in proto.graph.node for o in n.output}
    for n in proto.graph.node:
        if n.op_type in ("MatMul", "GatherElements", "GridSample", "Softmax"):
            assert all(producer[i].op_type not in QDQ for i in n.input if i in producer), n.name
    # a QDQ pair spliced before a MatMul is refused
    mm = next(n for n in proto.graph.node if n.op_type == "MatMul")
    q = onnx.helper.make_node("QuantizeLinear", [mm.input[0], "s", "z"], ["q_out"], name="stray_q")
    dq = onnx.helper.make_node("DequantizeLinear", ["q_out", "s", "z"], ["dq_out"], name="stray_dq")
    mm.input[0] = "dq_out"
    proto.graph.node.extend([q, dq])
    with pytest.raises(ExportError, match="not next to a Conv"):
        check_qdq_conv_only(proto)


def test_pose_close_to_fp32_on_simulated_sweeps(quantised, fast_learned_model, drives):
    out, report = quantised
    assert report.verify_sweeps == 9 and report.median_pose_cells <= 0.25
    a, b = OnnxModel(fast_learned_model, threads=1), OnnxModel(out, threads=1)
    feeds = stream_feeds(a.session, a.info, [sweeps(a.info, 3, 8, "urban")])
    res = a.info.profile.resolution_m
    d = np.array([np.abs(a.run(f)["pose"] - b.run(f)["pose"]).ravel() for f in feeds])
    assert np.all(np.isfinite(d))
    assert np.median(d[:, :2]) / res < 0.25 and np.median(d[:, 2]) < 2e-3


def test_failed_verification_writes_nothing(fast_learned_model, drives, tmp_path):
    calib, check = drives
    out = tmp_path / "m.onnx"
    out.write_bytes(b"old")
    never = Int8Tolerance(median_cells=-1.0, p95_cells=-1.0, median_yaw_rad=-1.0, p95_yaw_rad=-1.0)
    with pytest.raises(ExportError, match="strays from the fp32 graph"):
        quantize_model(fast_learned_model, out, drives=[c[:4] for c in calib], verify_drives=check,
                       tolerance=never)
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["m.onnx"]  # no temporary file left


def test_already_quantised_is_refused(quantised, tmp_path):
    out, _ = quantised
    with pytest.raises(ExportError, match="already quantised"):
        quantize_model(out, tmp_path / "x.onnx", drives=[np.zeros((3, 32, 32), np.float32)])


def test_first_and_last_conv_can_stay_float(fast_learned_model, drives, tmp_path):
    calib, check = drives
    out = tmp_path / "m.onnx"
    report = quantize_model(fast_learned_model, out, drives=[c[:4] for c in calib], verify_drives=check,
                            verify=False)  # the default keeps the first and last Conv float32
    convs = [n.name for n in onnx.load(str(fast_learned_model)).graph.node if n.op_type == "Conv"]
    assert report.conv_nodes == len(convs) - 2
    proto = onnx.load(str(out))
    check_qdq_conv_only(proto, float_convs=[convs[0], convs[-1]])
    producer = {o: n for n in proto.graph.node for o in n.output}
    for n in proto.graph.node:
        if n.name in (convs[0], convs[-1]):
            assert all(producer[i].op_type != "DequantizeLinear" for i in n.input[1:] if i in producer)
    assert OnnxModel(out).info.quantization["float_nodes"] == ["first", "last"]


def test_schema_quantization_key_is_an_optional_object(fast_learned_model):
    meta = dict(OnnxModel(fast_learned_model).session.get_modelmeta().custom_metadata_map)
    assert ModelInfo.from_metadata(meta).quantization is None
    q = {"scheme": "static", "op_types": ["Conv"]}
    assert ModelInfo.from_metadata({**meta, "radar_odom.quantization": json.dumps(q)}).quantization == q
    with pytest.raises(InvalidModelError, match="radar_odom.quantization"):
        ModelInfo.from_metadata({**meta, "radar_odom.quantization": "[1, 2]"})


def test_export_command_quantize_int8(tmp_path, monkeypatch, drives, capsys):
    """``radar-odom export CKPT --search fast --quantize int8``: the fp32 export (verified against
    torch), then the quantised file (verified against it); the temporary fp32 file is gone."""
    from radar_odom.commands.cli import main
    from radar_odom_export import quantize
    from radar_odom_export.checkpoint import save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    from fixtures import SMALL

    calib, check = drives
    monkeypatch.setattr(quantize, "calibration_drives", lambda info, **kw: calib + check)
    torch.manual_seed(0)
    ckpt = save_checkpoint(tmp_path / "m.pt", MaskedCorrelator(SMALL, masking="learned").eval(), "learned",
                           train={})
    out = tmp_path / "m-int8.onnx"
    assert main(["export", str(ckpt), "-o", str(out), "--search", "fast", "--quantize", "int8", "--no-calibrate"]) == 0
    text = capsys.readouterr().out
    assert "quantised" in text and "check: int8 vs fp32" in text
    info = OnnxModel(out).info
    assert info.quantization["op_types"] == ["Conv"] and info.search["kind"] == "coarse_to_fine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m-int8.onnx", "m.pt"]
    assert main(["export", str(ckpt), "--form", "pair", "--quantize", "int8", "-o", str(tmp_path / "p.onnx"),
                 "--no-calibrate"]) == 1


def test_scheme_is_static_int8_a_synonym():
    assert SCHEME == "static" and QUANTIZE_CHOICES[0] == "static" and "int8" in QUANTIZE_CHOICES
    assert quantize_scheme("static") == quantize_scheme("int8") == "static"
    with pytest.raises(ExportError, match="int8 is a synonym of static"):
        quantize_scheme("dynamic")


def test_torch_fp32_int8_tolerances_on_the_same_sweeps(quantised, fast_learned_model, tmp_path):
    """One set of sweeps through the torch model, its float32 ONNX export and the int8 copy of that export:
    torch vs float32 to float rounding (the export's own tolerance), int8 vs float32 within `Int8Tolerance`
    (a quantised masker is not float rounding), and int8 vs torch no further than that plus the rounding."""
    from radar_odom_export.checkpoint import save_checkpoint
    from radar_odom_export.model import MaskedCorrelator
    from radar_odom_export.onnx_export import export_checkpoint

    from fixtures import SMALL

    torch.manual_seed(0)
    model = MaskedCorrelator(SMALL, masking="learned").eval()
    ckpt = save_checkpoint(tmp_path / "m.pt", model, "learned", train={})
    fp32_path = tmp_path / "m.onnx"
    export_checkpoint(ckpt, fp32_path, form="stream", search="exhaustive", verify=False)
    info = OnnxModel(fp32_path, threads=1).info
    calib = [sweeps(info, 4, 8, "urban"), sweeps(info, 5, 8, "open")]
    check = [sweeps(info, 6, 9, "heavy_traffic")]
    int8_path = tmp_path / "m-int8.onnx"
    quantize_model(fp32_path, int8_path, drives=calib, verify_drives=check, calibration_every=1, exclude="")
    fp32, int8 = OnnxModel(fp32_path, threads=1), OnnxModel(int8_path, threads=1)
    assert int8.info.quantization["scheme"] == "static" and fp32.info.quantization is None
    res = info.profile.resolution_m
    feeds = stream_feeds(fp32.session, info, check)
    with torch.no_grad():
        images = torch.from_numpy(check[0])
        state = model.initial_state(images[:1])
        torch_poses = []
        for k in range(1, len(images)):
            pose, _, state = model.stream_step(images[k: k + 1], state)
            torch_poses.append(pose[0].double().numpy())
    torch_poses = np.array(torch_poses)
    a = np.array([fp32.run(f)["pose"].reshape(3) for f in feeds], dtype=np.float64)
    b = np.array([int8.run(f)["pose"].reshape(3) for f in feeds], dtype=np.float64)
    assert a.shape == b.shape == torch_poses.shape
    # torch vs float32 ONNX: float rounding (the exported graph's own check is 1e-3 m / 1e-4 rad class)
    assert np.max(np.abs(a[:, :2] - torch_poses[:, :2])) / res < 0.05
    assert np.max(np.abs(a[:, 2] - torch_poses[:, 2])) < 1e-3
    # int8 vs float32: the quantisation's tolerance (median and p95 over sweeps, in cells / rad)
    tol = Int8Tolerance()
    cells = np.abs(b[:, :2] - a[:, :2]).max(axis=1) / res
    yaw = np.abs(b[:, 2] - a[:, 2])
    assert np.median(cells) <= tol.median_cells and np.percentile(cells, 95) <= tol.p95_cells
    assert np.median(yaw) <= tol.median_yaw_rad and np.percentile(yaw, 95) <= tol.p95_yaw_rad
    # int8 vs torch: no further than the two together
    cells_t = np.abs(b[:, :2] - torch_poses[:, :2]).max(axis=1) / res
    assert np.median(cells_t) <= tol.median_cells + 0.05


@pytest.mark.real
def test_real_sweeps_join_the_calibration_but_never_the_held_out_stretch(fast_learned_model, drives, real_data_dir,
                                                                           tmp_path):
    """The shared RADIATE drive's sweeps (not its last 80, the scorecard's held-out stretch) calibrate too,
    and the metadata names them."""
    drive = real_data_dir / "radiate-2019-02-12-edinburgh"
    if not drive.is_dir():
        pytest.skip(f"{drive} not found")
    from radar_odom.io import read_sequence

    n = len(read_sequence(drive, repair_stamps=False))
    info = OnnxModel(fast_learned_model, threads=1).info
    imgs, prov = real_calibration_drives(info, [drive], max_sweeps=6)
    assert len(imgs) == 1 and imgs[0].shape == (6, *info.input_shape[-2:]) and imgs[0].dtype == np.float32
    assert prov == {"real": [{"recording": drive.name, "sweeps": [0, 6], "of": n, "held_out": REAL_HOLDOUT}]}
    whole, prov = real_calibration_drives(info, [drive], holdout=n - 3)  # the cut is the held-out count's
    assert len(whole[0]) == 3 and prov["real"][0]["sweeps"] == [0, 3]
    with pytest.raises(ExportError, match="fewer than two"):
        real_calibration_drives(info, [drive], holdout=n - 1)
    calib, check = drives
    out = tmp_path / "real-int8.onnx"
    report = quantize_model(fast_learned_model, out, drives=[c[:4] for c in calib], verify_drives=check,
                            calibration_every=1, real=[drive], real_max_sweeps=6, calibration={"seeds": [0, 1]})
    q = OnnxModel(out).info.quantization
    assert q["scheme"] == "static"
    assert q["calibration"]["real"] == [{"recording": drive.name, "sweeps": [0, 6], "of": n,
                                         "held_out": REAL_HOLDOUT}]
    assert q["calibration"]["seeds"] == [0, 1] and q["calibration"]["sweeps"] == 2 * 3 + 5
    assert "real: radiate-2019-02-12-edinburgh sweeps 0–5" in report.summary()
    assert 6 <= n - REAL_HOLDOUT  # the sweeps used lie before the held-out stretch
