"""The tiny models committed in tests/fixtures: they load in this runtime, and a fresh export matches.

The runtime tests read these files instead of exporting (so they run where torch is absent);
these tests keep them honest. Without torch: every file loads, its metadata passes the model-file
schema and it stays small. With torch: `make_models.make` re-exports each one into a temporary
folder and the result must match the committed file (metadata key by key but for the
version stamps, graph signature, and outputs on the same inputs). When one fails after a change
to the exporter or the schema, run ``python tests/fixtures/make_models.py`` and commit the files.
"""
import numpy as np
import pytest

from radar_odom.errors import ModelMismatchError
from radar_odom.odometry.odometer import RadarOdometer
from radar_odom.onnx_model import OnnxModel

from fixtures import FIXTURES, GEOM, MODELS
from fixtures.make_models import FOREIGN, MAX_BYTES, make

REGENERATE = "run `python tests/fixtures/make_models.py` and commit tests/fixtures/"
# provenance stamps that name the tools of the day, not the model
STAMPS = {"radar_odom.version", "radar_odom.torch_version"}


def metadata(model: OnnxModel) -> dict:
    return dict(model.session.get_modelmeta().custom_metadata_map)


def signature(model: OnnxModel):
    s = model.session
    return ([(i.name, i.shape, i.type) for i in s.get_inputs()], [(o.name, o.shape, o.type) for o in s.get_outputs()])


def feeds(model: OnnxModel, seed: int = 3) -> dict:
    """Random inputs; a symbolic dimension (the sequence form's sweep count) gets 3."""
    rng = np.random.default_rng(seed)
    return {i.name: rng.random([d if isinstance(d, int) else 3 for d in i.shape]).astype(np.float32)
            for i in model.session.get_inputs()}


def test_every_fixture_is_committed_and_small():
    assert sorted(FIXTURES) == sorted([*MODELS, FOREIGN])
    for name, path in FIXTURES.items():
        assert path.is_file(), f"{path} is missing: {REGENERATE}"
        assert 0 < path.stat().st_size < MAX_BYTES, name


@pytest.mark.parametrize("name", sorted(MODELS))
def test_fixture_loads_in_this_runtime_with_its_profile(name):
    profile, form, geometry, masking, search = MODELS[name]
    try:  # the sequence form is for radar_odom.odometry.batch, not the odometer
        model = OnnxModel(FIXTURES[name], threads=1) if form == "sequence" else \
            RadarOdometer(FIXTURES[name], threads=1)._model
    except ModelMismatchError as e:  # a schema change the files predate
        pytest.fail(f"{name} no longer loads ({e}): {REGENERATE}")
    info = model.info
    assert info.profile == profile and info.form == form and info.masking == masking
    assert (info.search is None) == (search == "exhaustive")
    if geometry is not None:
        assert info.sweep_geometry == GEOM
    out = model.run(feeds(model))
    assert all(np.all(np.isfinite(v)) for v in out.values())


def test_the_foreign_fixture_is_onnx_but_not_a_radar_odom_model():
    with pytest.raises(ModelMismatchError, match="not a radar-odom model"):
        RadarOdometer(FIXTURES[FOREIGN])


@pytest.mark.torch
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MODELS))
def test_a_fresh_export_matches_the_committed_fixture(name, tmp_path):
    pytest.importorskip("torch")
    fresh, committed = OnnxModel(make(name, tmp_path), threads=1), OnnxModel(FIXTURES[name], threads=1)
    new, old = metadata(fresh), metadata(committed)
    assert sorted(new) == sorted(old), f"{name}: the metadata keys changed: {REGENERATE}"
    differ = sorted(k for k in new if k not in STAMPS and new[k] != old[k])
    assert not differ, f"{name}: metadata {differ} changed: {REGENERATE}"
    assert signature(fresh) == signature(committed), f"{name}: the graph's inputs/outputs changed: {REGENERATE}"
    x = feeds(committed)
    a, b = fresh.session.run(None, x), committed.session.run(None, x)
    for out, u, v in zip(committed.session.get_outputs(), a, b):
        np.testing.assert_allclose(u, v, rtol=1e-4, atol=1e-5,
                                   err_msg=f"{name}: output {out.name} changed: {REGENERATE}")
