"""`radar_odom.match_sequence`: the sequence-form graph gives the stream form's numbers, pair by
pair, in any batch size, and refuses what it cannot match with a message saying what to do."""
import dataclasses

import numpy as np
import pytest

from radar_odom import ModelMismatchError, RadarOdometer, StreamError, match_sequence
from radar_odom.errors import ConfigError
from radar_odom.model_file import InvalidModelError, ModelInfo, check_signature
from radar_odom.odometry.batch import sequence_inputs
from radar_odom.onnx_model import OnnxModel

FRAMES = 9


@pytest.fixture(scope="module")
def scans():
    from radar_odom.sim.simulator import simulate_drive

    return [f.scan for f in simulate_drive(21, FRAMES, "urban")]


@pytest.fixture(scope="module")
def stream_measurements(fast_learned_model, scans):
    """The stream-form file's own measurements (no prior) of the same pairs."""
    odo = RadarOdometer(fast_learned_model, threads=1, motion_prior=False)
    steps = [odo.step(s) for s in scans][1:]
    return np.array([e.measurement for e in steps]), np.array([e.measurement_covariance for e in steps])


@pytest.mark.parametrize("batch", [1, 3, FRAMES - 1, 100])
def test_every_batch_size_gives_the_stream_forms_numbers(sequence_model, scans, stream_measurements, batch):
    out = match_sequence(sequence_model, scans, batch=batch, threads=1)
    pose, cov = stream_measurements
    assert out.poses.shape == (FRAMES - 1, 3) and out.covariances.shape == (FRAMES - 1, 3, 3)
    np.testing.assert_allclose(out.poses, pose, atol=1e-5)
    # float32 sums in another order: entries agree to 1e-5 of each covariance's largest one
    scale = np.abs(cov).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(out.covariances - cov) <= 1e-5 * scale)
    assert np.array_equal(out.timestamps_us, [s.timestamp_us for s in scans])
    assert np.allclose(out.covariances, out.covariances.transpose(0, 2, 1))


def test_array_input_matches_scan_input(sequence_model, scans):
    model = OnnxModel(sequence_model, threads=1)
    x, stamps = sequence_inputs(model, scans)
    a, b = match_sequence(model, x, batch=4), match_sequence(model, scans, batch=4)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert np.array_equal(a.timestamps_us, np.arange(FRAMES))
    assert x.dtype == np.float32 and x.shape == (FRAMES, *model.info.input_shape[1:])


def test_the_progress_bar_changes_nothing(sequence_model, scans):
    model = OnnxModel(sequence_model, threads=1)
    a = match_sequence(model, scans, batch=3, progress=True)
    np.testing.assert_array_equal(a.poses, match_sequence(model, scans, batch=3).poses)


def test_a_stream_model_is_refused_with_the_export_command(fast_learned_model, scans):
    with pytest.raises(ModelMismatchError, match="--form sequence"):
        match_sequence(fast_learned_model, scans)


def test_the_odometer_refuses_a_sequence_model(sequence_model):
    with pytest.raises(ModelMismatchError, match="match_sequence"):
        RadarOdometer(sequence_model)


def test_bad_sweeps_are_named(sequence_model, scans):
    model = OnnxModel(sequence_model, threads=1)
    with pytest.raises(StreamError, match="does not increase"):
        match_sequence(model, [scans[1], scans[0]])
    blank = dataclasses.replace(scans[2], power=np.zeros_like(scans[2].power))
    with pytest.raises(StreamError, match=r"degenerate sweep \(.*RadarOdometer"):
        match_sequence(model, [scans[0], scans[1], blank])
    with pytest.raises(ValueError, match="at least 2 sweeps"):
        match_sequence(model, scans[:1])
    x, _ = sequence_inputs(model, scans[:3])
    x[1, 0, 0] = np.nan
    with pytest.raises(ValueError, match=r"rows \[1\]"):
        match_sequence(model, x)
    with pytest.raises(ModelMismatchError, match=r"takes \[T, 32, 32\]"):
        match_sequence(model, np.zeros((3, 64, 64), np.float32))
    # an all-zero or constant image matched at a corner of the search window, without a word
    x, _ = sequence_inputs(model, scans[:3])
    for fill in (0.0, 0.5):
        y = x.copy()
        y[2] = fill
        with pytest.raises(StreamError, match=rf"sweep array rows \[2\] are degenerate \(one value throughout, e.g. "
                                              rf"row 2: {fill:g}"):
            match_sequence(model, y)
    with pytest.raises(StreamError, match=r"rows \[0, 1, 2\] are degenerate"):
        match_sequence(model, np.zeros_like(x))
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ConfigError, match="batch"):
            match_sequence(model, scans, batch=bad)


def test_a_sequence_graph_with_a_frozen_sweep_count_is_refused(sequence_model):
    model = OnnxModel(sequence_model, threads=1)
    s = model.session
    ins = [(i.name, i.shape, i.type) for i in s.get_inputs()]
    outs = [(o.name, o.shape, o.type) for o in s.get_outputs()]
    assert isinstance(ins[0][1][0], str)  # the committed file leaves the count free
    check_signature(model.info, ins, outs)
    frozen = [(ins[0][0], [5, *ins[0][1][1:]], ins[0][2])]
    with pytest.raises(InvalidModelError, match="fixed sweep count 5"):
        check_signature(model.info, frozen, outs)


def test_sequence_metadata_names_one_input(sequence_model):
    meta = dict(OnnxModel(sequence_model, threads=1).session.get_modelmeta().custom_metadata_map)
    info = ModelInfo.from_metadata(meta)
    assert info.form == "sequence" and info.inputs == ("carts",) and info.state_shape is None
    meta["radar_odom.inputs"] = '["carts", "prev_state"]'
    with pytest.raises(InvalidModelError, match="must name 1 tensors"):
        ModelInfo.from_metadata(meta)
