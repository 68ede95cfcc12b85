"""ONNX export: graph contents, opset, size, metadata, parity with torch, stream == pair, OpenVINO."""
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")

import cv2  # noqa: E402
from onnx import TensorProto, helper  # noqa: E402
from torch import nn  # noqa: E402

from radar_odom.errors import ExportError  # noqa: E402
from radar_odom.onnx_model import ModelInfo, OnnxModel  # noqa: E402
from radar_odom.profiles import GridProfile, get_profile  # noqa: E402
from radar_odom_export import onnx_export  # noqa: E402
from radar_odom_export.correlation import Rotator  # noqa: E402
from radar_odom_export.model import CTS350X_GEOMETRY, MaskedCorrelator  # noqa: E402
from radar_odom_export.onnx_export import (  # noqa: E402
    MAX_BYTES,
    InGraphRotator,
    StreamGraph,
    Tolerance,
    check_onnx_file,
    example_inputs,
    export_model,
    exportable,
    model_fields,
    op_counts,
    write_graph,
)

TINY = GridProfile("tiny-export", resolution_m=1.6, width_px=64, max_translation_m=4.8,
                   rotation_range_rad=0.1, rotation_step_rad=0.05, unet_base_channels=4, unet_depth=3)
SMALL_GEOM = {"num_azimuths": 120, "num_bins": 160, "range_resolution_m": 0.3, "range_offset_m": 0.0}


def seeded_model(profile, masking="learned", seed=0, **kw):
    torch.manual_seed(seed)  # untrained U-Net weights, the same every run
    return MaskedCorrelator(profile, masking=masking, **kw).eval()


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """Lazily exported tiny models, keyed by (mode, form): the model and its file."""
    folder = tmp_path_factory.mktemp("exports")
    cache = {}

    def get(mode="single", form="stream"):
        if (mode, form) not in cache:
            model = seeded_model(TINY.with_(mode=mode))
            path = folder / f"{mode}-{form}.onnx"
            report = export_model(model, path, form=form, verify=False)
            cache[mode, form] = (model, path, report)
        return cache[mode, form]

    return get


def scene_frames(width_px=64, steps=5, seed=0):
    """float32[steps, W, W] frames of a blob scene moving by a constant pixel shift and rotation."""
    rng = np.random.default_rng(seed)
    base = np.zeros((width_px, width_px), np.float32)
    idx = rng.integers(8, width_px - 8, size=(60, 2))
    base[idx[:, 0], idx[:, 1]] = rng.uniform(0.3, 1.0, size=60)
    base = cv2.GaussianBlur(base, (0, 0), 1.2)
    base /= base.max()
    c = (width_px - 1) / 2
    frames = []
    for k in range(steps):
        m = cv2.getRotationMatrix2D((c, c), 2.0 * k, 1.0)
        m[:, 2] += (1.0 * k, -1.0 * k)
        frames.append(cv2.warpAffine(base, m, (width_px, width_px)))
    return np.stack(frames).astype(np.float32)


# --------------------------------------------------------------------------- graph contents
@pytest.mark.parametrize("form", ["stream", "pair"])
def test_graph_has_no_dft_node_and_the_pinned_opset(exports, form):
    _, path, report = exports("single", form)
    proto = onnx.load(str(path))
    ops = op_counts(proto)
    assert not {"DFT", "STFT"} & set(ops)
    # the pieces the issue lists are in the graph: masker, rotation, matmul DFT, soft-argmax
    assert {"Conv", "GridSample", "MatMul", "Softmax"} <= set(ops)
    assert [o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")] == [18]
    assert report.opset == 18 and report.exporter in ("dynamo", "torchscript")
    onnx.checker.check_model(proto, full_check=True)
    assert not any(t.data_location == TensorProto.EXTERNAL for t in proto.graph.initializer)
    names_in = [i.name for i in proto.graph.input]
    names_out = [o.name for o in proto.graph.output]
    if form == "stream":
        assert names_in == ["cart", "prev_state"] and names_out == ["pose", "covariance", "state"]
    else:
        assert names_in == ["prev_cart", "cart"] and names_out == ["pose", "covariance"]
    shapes = {o.name: [d.dim_value for d in o.type.tensor_type.shape.dim] for o in proto.graph.output}
    assert shapes["pose"] == [1, 3] and shapes["covariance"] == [1, 3, 3]


def _model_with(nodes, functions=()):
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [4])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [4])
    graph = helper.make_graph(nodes, "g", [x], [y])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18), helper.make_opsetid("local", 1)],
                             functions=list(functions))


def test_graph_walk_finds_forbidden_ops_in_subgraphs_and_functions(tmp_path):
    inner = helper.make_graph([helper.make_node("DFT", ["x"], ["y"])], "then", [],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)])
    other = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "else", [],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)])
    cond = helper.make_node("Constant", [], ["c"], value=helper.make_tensor("c", TensorProto.BOOL, [], [True]))
    branch = helper.make_node("If", ["c"], ["y"], then_branch=inner, else_branch=other)
    fn = helper.make_function("local", "Spectral", ["a"], ["b"], [helper.make_node("STFT", ["a"], ["b"])],
                              [helper.make_opsetid("", 18)])
    proto = _model_with([cond, branch], [fn])
    ops = op_counts(proto)
    assert ops["DFT"] == 1 and ops["STFT"] == 1 and ops["If"] == 1
    path = tmp_path / "bad.onnx"
    onnx.save(proto, str(path))
    with pytest.raises(ExportError, match="DFT"):
        check_onnx_file(path, opset=18)


def test_check_refuses_a_different_opset_and_oversize(exports):
    _, path, _ = exports("single", "stream")
    with pytest.raises(ExportError, match="opset 18.*opset 17 was requested"):
        check_onnx_file(path, opset=17)
    with pytest.raises(ExportError, match="budget"):
        check_onnx_file(path, opset=18, max_bytes=1000)


def test_in_graph_rotation_equals_the_precomputed_grids():
    rot = Rotator(TINY)
    ingraph = InGraphRotator(rot, TINY.rotations_rad, TINY.width_px)
    x = torch.from_numpy(scene_frames(steps=2)[1:])
    # grids built in float32 in the graph vs float64 then rounded: agree to float32 precision
    np.testing.assert_allclose(ingraph(x).numpy(), rot(x).numpy(), atol=1e-5)


# --------------------------------------------------------------------------- metadata
def test_metadata_describes_the_model_completely(exports):
    model, path, _ = exports("single", "stream")
    ort_model = OnnxModel(path)
    meta = dict(ort_model.session.get_modelmeta().custom_metadata_map)
    assert meta["radar_odom.profile"] == model.profile.to_metadata()["radar_odom.profile"]
    info = ModelInfo.from_metadata(meta)
    assert GridProfile.from_metadata(meta) == model.profile == info.profile
    assert info.form == "stream" and info.masking == "learned"
    assert info.sweep_geometry == CTS350X_GEOMETRY
    assert info.inputs == ("cart", "prev_state") and info.outputs == ("pose", "covariance", "state")
    session_shapes = {i.name: tuple(i.shape) for i in ort_model.session.get_inputs()}
    assert session_shapes["cart"] == info.input_shape == (1, 64, 64)
    assert session_shapes["prev_state"] == info.state_shape == (1, 2, 64, 33)
    import radar_odom

    assert info.version == radar_odom.__version__ and info.opset == 18
    assert info.exporter in ("dynamo", "torchscript")


# --------------------------------------------------------------------------- behaviour
@pytest.mark.parametrize("mode", ["single", "dual"])
def test_stream_and_pair_forms_give_the_same_poses(exports, mode):
    """Over a short sequence, the stream graph (state carried between steps) gives the poses of
    the pair form: the ONNX pair graph in single mode, the torch pair forward (FFT) in both."""
    model, stream_path, _ = exports(mode, "stream")
    stream = OnnxModel(stream_path)
    pair = OnnxModel(exports(mode, "pair")[1]) if mode == "single" else None
    frames = scene_frames(steps=5)[:, None]
    state = np.zeros(stream.info.state_shape, np.float32)
    state = stream.run({"cart": frames[0], "prev_state": state})["state"]
    for k in range(1, len(frames)):
        s = stream.run({"cart": frames[k], "prev_state": state})
        state = s["state"]
        with torch.no_grad():
            ref_pose, ref_cov = model(torch.from_numpy(frames[k - 1]), torch.from_numpy(frames[k]))
        np.testing.assert_allclose(s["pose"], ref_pose.numpy(), atol=2e-5)
        np.testing.assert_allclose(s["covariance"], ref_cov.numpy(), atol=2e-5, rtol=1e-4)
        if pair is not None:
            p = pair.run({"prev_cart": frames[k - 1], "cart": frames[k]})
            np.testing.assert_allclose(s["pose"], p["pose"], atol=2e-5)
            np.testing.assert_allclose(s["covariance"], p["covariance"], atol=2e-5, rtol=1e-4)


def test_polar_model_exports_and_the_runtime_reduces_sweeps_as_documented(tmp_path):
    from radar_odom.odometry.odometer import RadarOdometer
    from radar_odom.scan import RadarScan

    profile = TINY.with_(name="tiny-polar", input_kind="polar", unet_depth=2)
    model = seeded_model(profile, sweep_geometry=SMALL_GEOM)
    path = tmp_path / "polar.onnx"
    report = export_model(model, path, verify=True)
    assert report.max_pose_diff < 1e-4
    info = OnnxModel(path).info
    a, nb = model.to_cartesian.input_shape
    f = model.to_cartesian.bin_factor
    assert info.inputs == ("polar", "prev_state") and info.input_shape == (1, a, nb)
    assert info.polar_input == {"num_bins": nb, "bin_factor": f}
    rng = np.random.default_rng(3)
    # smoothed random fields: structure like a scene's (i.i.d. noise is a degenerate sweep)
    powers = [cv2.GaussianBlur(rng.random((a, SMALL_GEOM["num_bins"])).astype(np.float32), (0, 0), 2.0) ** 6
              for _ in range(2)]
    az = 2 * np.pi * np.arange(a) / a
    odo = RadarOdometer(path)
    for k, power in enumerate(powers):
        est = odo.step(RadarScan.from_arrays(10**15 + k * 250_000 + np.arange(a), az, power,
                                             range_resolution_m=SMALL_GEOM["range_resolution_m"]))
    # the model's documented input: the first nb·f bins averaged in groups of f
    reduced = [torch.from_numpy(p[:, : nb * f].reshape(a, nb, f).mean(-1))[None] for p in powers]
    with torch.no_grad():
        ref_pose, _ = model(*reduced)
    np.testing.assert_allclose(est.pose, ref_pose[0].numpy(), atol=1e-4)


def test_export_command_from_a_checkpoint(tmp_path, capsys):
    from radar_odom.commands.cli import main
    from radar_odom_export.checkpoint import save_checkpoint

    model = seeded_model(TINY.with_(beta_cov=0.37))
    ckpt = save_checkpoint(tmp_path / "m.pt", model, "learned", train={"command": "radar-odom train ...",
                                                                       "seeds": [1000, 1001]})
    out = tmp_path / "m.onnx"
    assert main(["export", str(ckpt), "-o", str(out), "--no-calibrate"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "onnxruntime vs torch" in printed
    info = OnnxModel(out).info
    assert info.profile.beta_cov == 0.37 and info.masking == "learned"
    assert json.loads(info.training_data)["train"]["seeds"] == [1000, 1001]


def test_export_command_writes_the_fast_search_when_asked(tmp_path, capsys):
    from radar_odom.commands.cli import main
    from radar_odom_export.checkpoint import save_checkpoint

    # 13 yaws, a step that divides the full turn (the polar rotator needs it): the band is narrower
    profile = TINY.with_(rotation_range_rad=math.radians(18), rotation_step_rad=math.radians(3))
    ckpt = save_checkpoint(tmp_path / "m.pt", seeded_model(profile), "learned", train={})
    fast, exhaustive = tmp_path / "fast.onnx", tmp_path / "exhaustive.onnx"
    assert main(["export", str(ckpt), "-o", str(fast), "--no-calibrate"]) == 0  # fast: the default, as shipped
    assert main(["export", str(ckpt), "-o", str(exhaustive), "--search", "exhaustive", "--no-calibrate"]) == 0
    assert OnnxModel(fast).info.search["kind"] == "coarse_to_fine"
    assert OnnxModel(exhaustive).info.search is None
    capsys.readouterr()
    assert main(["export", str(ckpt), "--form", "pair", "--search", "fast"]) == 1
    assert "stream and sequence forms" in capsys.readouterr().err
    assert main(["export", str(ckpt), "--form", "sequence", "--search", "exhaustive"]) == 1
    assert "fast search only; add --search fast" in capsys.readouterr().err


def test_export_command_picks_the_fast_search_for_the_sequence_form(tmp_path, monkeypatch):
    """--form sequence alone asks for the fast search (the only one it has), no --form the fast
    search too (as the shipped models), --form pair the exhaustive one; the export itself is
    tested on the committed sequence fixture (test_fixture_models)."""
    from radar_odom.commands.cli import main
    from radar_odom_export.checkpoint import save_checkpoint

    asked = []
    monkeypatch.setattr(onnx_export, "export_checkpoint",
                        lambda ckpt, out, **kw: asked.append(kw) or SimpleNamespace(summary=lambda: "ok"))
    profile = TINY.with_(rotation_range_rad=math.radians(18), rotation_step_rad=math.radians(3))  # divides the turn
    ckpt = save_checkpoint(tmp_path / "m.pt", seeded_model(profile), "learned", calibration={"test": "export only"})
    odd = save_checkpoint(tmp_path / "odd.pt", seeded_model(TINY), "learned", calibration={"test": "export only"})
    assert main(["export", str(ckpt), "--form", "sequence"]) == 0
    assert main(["export", str(ckpt)]) == 0
    assert main(["export", str(ckpt), "--form", "pair", "--force"]) == 0
    assert main(["export", str(odd)]) == 0  # a yaw step that does not divide the turn: the polar rotation cannot
    assert [(a["form"], a["search"]) for a in asked] == [("sequence", "fast"), (None, "fast"), ("pair", "exhaustive"),
                                                         (None, "exhaustive")]


def test_export_command_writes_the_sweep_form(tmp_path, capsys):
    """--form sweep: the stream graph with the drawing in front, checked against the SDK path before it is written;
    nothing but the output is left beside it."""
    from radar_odom.commands.cli import main
    from radar_odom_export.checkpoint import save_checkpoint

    ckpt = save_checkpoint(tmp_path / "m.pt", seeded_model(TINY), "learned", train={})
    out = tmp_path / "m-sweep.onnx"
    assert main(["export", str(ckpt), "--form", "sweep", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "sweep form: wrote" in printed and "against the stream graph on the SDK's Cartesian image" in printed
    info = OnnxModel(out).info
    assert info.form == "sweep" and info.inputs[0] == "power" and info.masking == "learned"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m-sweep.onnx", "m.pt"]


def test_export_command_keeps_a_shipped_models_search_in_the_sweep_form(tmp_path, monkeypatch):
    from radar_odom.commands.cli import main
    from radar_odom.model_zoo import shipped_export
    from radar_odom_export import sweep_form

    asked = []
    monkeypatch.setattr(sweep_form, "export_sweep_checkpoint",
                        lambda ckpt, out, **kw: asked.append((out, kw)) or SimpleNamespace(summary=lambda: "ok"))
    monkeypatch.chdir(tmp_path)
    assert main(["export", "cart-0.4", "--form", "sweep"]) == 0
    shipped = shipped_export("cart-0.4")
    out, kw = asked[0]
    assert str(out) == "cart-0.4-sweep.onnx" and kw["form"] == "sweep"
    assert kw["search"] == shipped["search"] and kw["search_settings"] == shipped["settings"]


def test_export_command_reports_a_bad_checkpoint(tmp_path, capsys):
    from radar_odom.commands.cli import main

    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    assert main(["export", str(bad)]) == 1
    assert "not a radar-odom checkpoint" in capsys.readouterr().err


# --------------------------------------------------------------------------- one export path
class _LiesUnderExport(nn.Module):
    """The stream graph, but its pose moves by 0.5 m while being exported: a graph that is not
    the model (what a branch frozen at trace time looks like), which verification must catch."""

    def __init__(self, graph):
        super().__init__()
        self.graph = graph

    def forward(self, sweep, prev_state):
        pose, cov, state = self.graph(sweep, prev_state)
        if torch.onnx.is_in_onnx_export():
            pose = pose + 0.5
        return pose, cov, state


def _write(module, path, model, **kw):
    inputs = example_inputs(model, "stream", seed=0)
    fields = model_fields(model, "stream", None, None, tuple(inputs[1].shape))
    return write_graph(module, inputs, path, fields, input_names=["cart", "prev_state"],
                       output_names=["pose", "covariance", "state"],
                       verify_inputs=example_inputs(model, "stream", seed=1), **kw)


def test_export_error_is_the_public_one():
    import radar_odom.errors

    assert onnx_export.ExportError is radar_odom.errors.ExportError
    assert "ExportError" not in vars(onnx_export) or onnx_export.ExportError is ExportError


def test_an_export_that_differs_from_torch_fails_and_leaves_the_destination_untouched(tmp_path):
    m = exportable(seeded_model(TINY))
    path = tmp_path / "m.onnx"
    with pytest.raises(ExportError, match="disagree.*nothing was written"):
        _write(_LiesUnderExport(StreamGraph(m)), path, m, exporter="torchscript")
    assert list(tmp_path.iterdir()) == []  # no file, no temporary left behind
    path.write_bytes(b"the previous model")
    with pytest.raises(ExportError, match="disagree"):
        _write(_LiesUnderExport(StreamGraph(m)), path, m, exporter="torchscript")
    assert path.read_bytes() == b"the previous model" and list(tmp_path.iterdir()) == [path]


def test_the_tolerance_fails_an_export_and_a_failed_check_writes_nothing(tmp_path, monkeypatch):
    model = seeded_model(TINY)
    path = tmp_path / "m.onnx"
    path.write_bytes(b"old")
    with pytest.raises(ExportError, match="disagree"):  # nothing is exact: a zero tolerance fails
        export_model(model, path, tolerance=Tolerance(pose_m=0.0, yaw_rad=0.0, covariance=0.0))
    assert path.read_bytes() == b"old" and sorted(tmp_path.iterdir()) == [path]

    def refuse(*a, **k):
        raise ExportError("refused by a check")

    monkeypatch.setattr(onnx_export, "check_onnx_file", refuse)
    with pytest.raises(ExportError, match="refused by a check"):
        export_model(model, path, verify=False)
    assert path.read_bytes() == b"old" and sorted(tmp_path.iterdir()) == [path]


def test_a_verified_export_replaces_the_file_and_reports_both_differences(tmp_path):
    path = tmp_path / "m.onnx"
    path.write_bytes(b"old")
    report = export_model(seeded_model(TINY), path)
    assert report.max_pose_diff < 1e-4 and report.max_cov_diff < 1e-3
    assert "covariance" in report.summary() and OnnxModel(path).info.profile == TINY
    assert sorted(tmp_path.iterdir()) == [path]


def test_verification_needs_fresh_inputs(tmp_path):
    m = exportable(seeded_model(TINY))
    inputs = example_inputs(m, "stream", seed=0)
    fields = model_fields(m, "stream", None, None, tuple(inputs[1].shape))
    with pytest.raises(ValueError, match="fresh"):
        write_graph(StreamGraph(m), inputs, tmp_path / "m.onnx", fields, input_names=["cart", "prev_state"],
                    output_names=["pose", "covariance", "state"], verify_inputs=inputs)
    assert list(tmp_path.iterdir()) == []


def test_auto_falls_back_only_when_the_exporter_itself_fails(tmp_path, monkeypatch):
    real = onnx_export._run_exporter
    model = seeded_model(TINY)

    def broken(kind, *a, **k):
        if kind == "dynamo":
            raise ValueError("a bug in the model code")
        return real(kind, *a, **k)

    monkeypatch.setattr(onnx_export, "_run_exporter", broken)
    with pytest.raises(ValueError, match="a bug"):  # not hidden behind a TorchScript fallback
        export_model(model, tmp_path / "a.onnx", verify=False)

    def exporter_fails(kind, *a, **k):
        if kind == "dynamo":
            raise torch.onnx.errors.OnnxExporterError("cannot convert op")
        return real(kind, *a, **k)

    monkeypatch.setattr(onnx_export, "_run_exporter", exporter_fails)
    with pytest.warns(RuntimeWarning, match="dynamo exporter failed.*falling back"):
        report = export_model(model, tmp_path / "b.onnx", verify=False)
    assert report.exporter == "torchscript" and "fell back" in report.summary()
    assert OnnxModel(tmp_path / "b.onnx").info.exporter == "torchscript"
    with pytest.raises(ExportError, match="dynamo exporter failed"):
        export_model(model, tmp_path / "c.onnx", verify=False, exporter="dynamo")
    assert not (tmp_path / "c.onnx").exists()


def test_exporter_warnings_that_concern_the_graph_are_passed_on(tmp_path, monkeypatch):
    import warnings

    real = torch.onnx.export

    def chatty(*a, **k):
        warnings.warn("the legacy exporter is deprecated", DeprecationWarning, stacklevel=2)
        warnings.warn("Converting a tensor to a Python boolean might cause the trace to be incorrect",
                      torch.jit.TracerWarning, stacklevel=2)
        return real(*a, **k)

    monkeypatch.setattr(torch.onnx, "export", chatty)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = export_model(seeded_model(TINY), tmp_path / "m.onnx", verify=False)
    shown = [str(w.message) for w in caught]
    assert any("trace to be incorrect" in m for m in shown)
    assert not any("deprecated" in m for m in shown)
    assert any("TracerWarning" in n for n in report.notes)


# --------------------------------------------------------------------------- real size
@pytest.mark.slow
def test_parity_with_torch_fft_on_real_sized_sweeps(tmp_path):
    """cart-0.4 (W = 256, 61 yaws): onnxruntime vs the torch FFT path on simulated sweeps.

    β is lowered so that the soft-argmax spreads over several cells (correlation values of the
    normalised sweeps are in the thousands; 0.05 sufficed for the unnormalised power of profiles
    before ``input_norm``): the regime where the pose and covariance depend on the most volume
    entries, so volume errors would show.
    """
    from radar_odom.polar import polar_to_cartesian
    from radar_odom.sim import simulate_drive

    profile = get_profile("cart-0.4").with_(beta_pose=0.02, beta_cov=0.02)
    assert profile.input_norm == "floor-scale"  # the normalisation is in the parity check too
    model = seeded_model(profile, masking="raw")
    path = tmp_path / "cart04.onnx"
    report = export_model(model, path, verify=False)
    assert report.bytes <= MAX_BYTES
    ort_model = OnnxModel(path)
    carts = [polar_to_cartesian(f.scan, profile.resolution_m, profile.width_px, near_range_m=profile.near_range_m)[None]
             for f in simulate_drive(seed=12, frames=3)]
    state = ort_model.run({"cart": carts[0], "prev_state": np.zeros(ort_model.info.state_shape, np.float32)})["state"]
    for prev, cur in zip(carts[:-1], carts[1:]):
        out = ort_model.run({"cart": cur, "prev_state": state})
        state = out["state"]
        with torch.no_grad():
            pose, cov = model(torch.from_numpy(prev), torch.from_numpy(cur))
        pose, cov = pose[0].numpy(), cov[0].numpy()
        assert np.all(np.abs(out["pose"][0, :2] - pose[:2]) <= 1e-3)
        assert abs(out["pose"][0, 2] - pose[2]) <= 1e-4
        assert np.linalg.norm(out["covariance"][0] - cov) <= 1e-3 * np.linalg.norm(cov)
        assert 0.05 < cov[0, 0] < 10.0  # the spread regime the docstring promises, not a hard argmax


@pytest.mark.slow
def test_finest_profile_fits_the_size_budget(tmp_path):
    """cart-0.2 with the paper's U-Net: rotation grids (126 MB as constants) must not be stored."""
    model = seeded_model(get_profile("cart-0.2"))
    report = export_model(model, tmp_path / "cart02.onnx", verify=False)
    assert report.bytes <= MAX_BYTES
    proto = onnx.load(str(tmp_path / "cart02.onnx"))
    biggest = max(int(np.prod(t.dims)) for t in proto.graph.initializer)
    assert biggest < 512 * 512 * 2 * 8  # far below even two W×W×2 grids


@pytest.mark.portability
def test_openvino_gives_the_same_outputs(exports):
    ov = pytest.importorskip("openvino")
    _, path, _ = exports("single", "stream")
    ort_model = OnnxModel(path)
    from radar_odom.runtimes import OPENVINO_CPU_CONFIG

    # f32 (OpenVINO's CPU plugin defaults to bf16 where the CPU has it; the DFT matmuls need float32) and no
    # Snippets fusion (it moves the shipped graphs' poses by centimetres): radar_odom.runtimes
    compiled = ov.Core().compile_model(str(path), "CPU", OPENVINO_CPU_CONFIG)
    frames = scene_frames(steps=2)[:, None]
    state = ort_model.run({"cart": frames[0], "prev_state": np.zeros(ort_model.info.state_shape, np.float32)})["state"]
    feeds = {"cart": frames[1], "prev_state": state}
    want = ort_model.run(feeds)
    got = compiled(feeds)
    for name in ("pose", "covariance", "state"):
        np.testing.assert_allclose(got[compiled.output(name)], want[name], atol=1e-4, rtol=1e-4, err_msg=name)



def handed_model(profile):
    """`seeded_model` with every 3×3 kernel's left column raised: a masker whose masks of a scene and
    of its mirror image differ clearly (masks up to 0.05 apart on `scene_frames`)."""
    model = seeded_model(profile)
    with torch.no_grad():
        for layer in model.masker.modules():
            if isinstance(layer, nn.Conv2d) and layer.kernel_size[-1] == 3:
                layer.weight[..., 0] += 0.05
    return model


@pytest.mark.torch
def test_a_mirror_averaged_masker_exports_and_reads_a_mirrored_scene_mirrored(tmp_path):
    """``GridProfile.mask_mirror_average``: the U-Net runs on the sweep and its mirror image as one
    batch (one Conv node per layer, as without it) and the masks are averaged over the mirror. The
    file matches torch, and a scene whose columns are reversed reads (x, −y, −yaw) through the file,
    where the same handed masker without the average reads it millimetres off."""
    profile = TINY.with_(name="tiny-mirror", mask_downsample=2, mask_mirror_average=True)
    frames = scene_frames(steps=3)[:, None]
    mirrored = np.ascontiguousarray(frames[..., ::-1])
    flip = np.array([1.0, -1.0, -1.0])
    with torch.no_grad():  # the masker is handed: without the average the mirrored pair reads otherwise
        plain = handed_model(profile.with_(mask_mirror_average=False))
        a, b = (plain(torch.from_numpy(f[0]), torch.from_numpy(f[1]))[0][0].numpy() for f in (frames, mirrored))
    assert np.abs(a - b * flip)[:2].max() > 1e-3
    model = handed_model(profile)
    path = tmp_path / "mirror.onnx"
    report = export_model(model, path, verify=True)
    assert report.max_pose_diff < 1e-4
    assert report.ops["Conv"] == sum(isinstance(layer, nn.Conv2d) for layer in model.masker.modules())
    m = OnnxModel(path)
    assert m.info.profile.mask_mirror_average

    def poses(seq):
        state = m.run({"cart": seq[0], "prev_state": np.zeros(m.info.state_shape, np.float32)})["state"]
        out = []
        for f in seq[1:]:
            r = m.run({"cart": f, "prev_state": state})
            state = r["state"]
            out.append(r["pose"][0])
        return np.array(out)

    a, b = poses(frames), poses(mirrored)
    for k in range(1, len(frames)):
        with torch.no_grad():
            ref, _ = model(torch.from_numpy(frames[k - 1]), torch.from_numpy(frames[k]))
        np.testing.assert_allclose(a[k - 1], ref[0].numpy(), atol=2e-5)
    np.testing.assert_allclose(b * flip, a, atol=1e-5)
