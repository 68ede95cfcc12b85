"""The model-file schema (`radar_odom.model_file`): one definition the exporter writes with and the
runtime reads with, checked against the graph onnxruntime loads. Needs no torch."""
import json

import pytest

from radar_odom.errors import InvalidModelError
from radar_odom.model_file import (
    KEYS,
    REQUIRED_KEYS,
    SCHEMA,
    ModelInfo,
    build_metadata,
    check_signature,
    expected_state_shape,
)
from radar_odom.model_zoo import pretrained, pretrained_names
from radar_odom.onnx_model import OnnxModel


@pytest.fixture(scope="module")
def shipped():
    if "cart-0.8" not in pretrained_names():
        pytest.skip("the shipped cart-0.8 model is not installed")
    model = OnnxModel(pretrained("cart-0.8"), threads=1)
    return model, dict(model.session.get_modelmeta().custom_metadata_map)


def rewritten(info: ModelInfo, **changes) -> dict:
    """The metadata `build_metadata` writes for what ``info`` describes."""
    fields = dict(profile=info.profile, form=info.form, sweep_geometry=info.sweep_geometry,
                  input_shape=info.input_shape, state_shape=info.state_shape, polar_input=info.polar_input,
                  masking=info.masking, training_data=info.training_data, version=info.version,
                  opset=info.opset, exporter=info.exporter, torch_version=info.torch_version, search=info.search)
    fields.update(changes)
    return build_metadata(**fields)


def test_the_writer_writes_what_the_shipped_files_hold(shipped):
    _, meta = shipped
    info = ModelInfo.from_metadata(meta)
    assert rewritten(info) == meta  # the shipped files load unchanged and re-write identically
    assert set(meta) <= set(KEYS) and set(REQUIRED_KEYS) <= set(meta)
    assert all(k.default is None for k in SCHEMA if k.required != "optional")  # required: no defaults


def test_optional_keys_read_their_stated_defaults(shipped):
    _, meta = shipped
    bare = {k: v for k, v in meta.items() if KEYS[k].required != "optional"}
    info = ModelInfo.from_metadata(bare)
    assert info.masking == KEYS["radar_odom.masking"].default == "unknown"
    assert info.opset is None and info.search is None and info.exporter == ""


def test_the_writer_refuses_what_the_reader_would(shipped):
    info = ModelInfo.from_metadata(shipped[1])
    with pytest.raises(InvalidModelError, match="input_shape"):
        rewritten(info, input_shape=(1, 64, 64))
    with pytest.raises(InvalidModelError, match="state_shape.*does not match the profile"):
        rewritten(info, state_shape=(1, 2, 128, 64))
    with pytest.raises(ValueError, match="form"):
        rewritten(info, form="both")


def test_a_missing_profile_is_named_not_reported_as_a_format_mismatch(shipped):
    """Without radar_odom.profile the message read "'radar_odom.format' is 'radar-odom-onnx/1', expected
    'radar-odom-onnx/1'" (a ModelMismatchError): now the missing key is named (InvalidModelError)."""
    from radar_odom.errors import ModelMismatchError

    meta = {k: v for k, v in shipped[1].items() if k != "radar_odom.profile"}
    with pytest.raises(InvalidModelError, match=r"m\.onnx: metadata lacks 'radar_odom\.profile'") as e:
        ModelInfo.from_metadata(meta, source="m.onnx")
    assert "expected" not in str(e.value)
    with pytest.raises(ModelMismatchError, match=r"not a radar-odom model \(metadata 'radar_odom\.format' is None"):
        ModelInfo.from_metadata({k: v for k, v in meta.items() if k != "radar_odom.format"}, source="m.onnx")


def test_the_state_shape_follows_the_mode(shipped):
    info = ModelInfo.from_metadata(shipped[1])
    assert expected_state_shape(info.profile, info.input_shape) == (1, 2, 128, 65)
    dual = info.profile.with_(mode="dual")
    assert expected_state_shape(dual, info.input_shape) == (1, 128, 128)


def signature(model):
    def described(args):
        return [(a.name, list(a.shape), a.type) for a in args]

    return described(model.session.get_inputs()), described(model.session.get_outputs())


def test_the_signature_check_reads_the_sessions_shapes(shipped):
    model, meta = shipped
    inputs, outputs = signature(model)
    check_signature(model.info, inputs, outputs)
    narrow = [("cart", [1, 128, 120], "tensor(float)"), inputs[1]]
    with pytest.raises(InvalidModelError, match=r"'cart' has shape \[1, 128, 120\]"):
        check_signature(model.info, narrow, outputs)
    doubles = [inputs[0], ("prev_state", inputs[1][1], "tensor(double)")]
    with pytest.raises(InvalidModelError, match="tensor\\(double\\)"):
        check_signature(model.info, doubles, outputs)
    no_state = [o for o in outputs if o[0] != "state"]
    with pytest.raises(InvalidModelError, match="lack"):
        check_signature(model.info, inputs, no_state)
    # metadata and graph agree with each other but not with the profile: still refused
    edited = dict(meta, **{"radar_odom.state_shape": json.dumps([1, 2, 128, 64])})
    info = ModelInfo.from_metadata(edited)
    graph_like = [inputs[0], ("prev_state", [1, 2, 128, 64], "tensor(float)")]
    with pytest.raises(InvalidModelError, match="state_shape.*does not match the profile"):
        check_signature(info, graph_like, [(n, [1, 2, 128, 64] if n == "state" else s, t) for n, s, t in outputs])
