"""The sweep form (docs/sweep-form.md): the shipped stream graphs with the polar→Cartesian drawing inside give
the SDK path's poses (stream graph on `polar_to_cartesian`'s image), draw its image on other sweep geometries,
and carry their form in the metadata, which `RadarOdometer` runs and the schema holds."""
import math

import numpy as np
import pytest

import radar_odom
from radar_odom import RadarOdometer, polar_to_cartesian
from radar_odom.errors import ConfigError, InvalidModelError
from radar_odom.model_file import SWEEP_INPUTS
from radar_odom.odometry.sweep_input import sweep_feeds
from radar_odom.onnx_model import OnnxModel
from radar_odom.profiles import get_profile
from radar_odom.scan import RadarScan
from radar_odom.sim import simulate_drive

POSE_M, YAW_RAD = 1e-3, 1e-4  # the parity bound
SWEEPS = {"cart-0.4": 10, "cart-0.8": 6}  # a short recording each (the front end is one for both grids)


def _needs_exact_remap():
    """The SDK path draws with cv2.remap: OpenCV 4 rounds its sample positions to 1/32 of a cell (the SDK's own
    poses then move by up to 4 mm, docs/sweep-form.md), OpenCV 5 samples where asked, as the graph does."""
    import cv2

    if int(cv2.__version__.split(".")[0]) < 5:
        pytest.skip(f"OpenCV {cv2.__version__} rounds remap positions to 1/32 cell: the SDK path is not the exact "
                    "drawing the sweep form is held to (docs/sweep-form.md)")


def _drive(seed: int, frames: int) -> list:
    return [f.scan for f in simulate_drive(seed=seed, frames=frames)]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cart-0.4", "cart-0.8"])
def test_poses_equal_the_sdk_path_over_a_recording(sweep_form_models, name):
    _needs_exact_remap()
    scans = _drive(seed=11, frames=SWEEPS[name])
    sdk = RadarOdometer(radar_odom.pretrained(name), threads=1)
    graph = RadarOdometer(sweep_form_models[name], threads=1)
    assert graph.info.form == "sweep" and sdk.info.form == "stream"
    for scan in scans:
        a, b = sdk.step(scan), graph.step(scan)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_allclose(b.pose[:2], a.pose[:2], atol=POSE_M)
            np.testing.assert_allclose(b.pose[2], a.pose[2], atol=YAW_RAD)
            assert b.flags == a.flags
    # a real drive, not standing still: the parity says something
    travelled = np.linalg.norm(sdk.trajectory.poses[-1][:2, 2])
    assert travelled > 5.0
    np.testing.assert_allclose(graph.trajectory.poses[-1][:2, 2], sdk.trajectory.poses[-1][:2, 2],
                               atol=SWEEPS[name] * POSE_M)


def _frontend_session(profile):
    onnx = pytest.importorskip("onnx", reason="onnx (the export extra) builds the sweep form")
    import onnxruntime as ort

    from radar_odom_export.sweep_form import sweep_frontend

    proto = sweep_frontend(profile.resolution_m, profile.width_px, profile.near_range_m, 18, onnx.IR_VERSION)
    return ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])


def _geometry_scan(rng, rows: int, bins: int, res: float, offset: float, jitter: float = 0.0, dropped=()):
    az = (np.arange(rows) + 0.5 + jitter * rng.uniform(-1, 1, rows)) * (2 * math.pi / rows)
    valid = np.ones(rows, bool)
    valid[list(dropped)] = False
    power = rng.random((rows, bins), dtype=np.float32) ** 6
    return RadarScan.from_arrays(np.arange(rows) * 625 + 10**15, az, power, valid=valid, range_resolution_m=res,
                                 range_offset_m=offset)


@pytest.mark.parametrize("geometry", [
    dict(rows=400, bins=3360, res=0.0596, offset=-0.31),  # Boreas
    dict(rows=400, bins=576, res=0.1736, offset=0.0),  # RADIATE: shorter than the grid's corners
    dict(rows=400, bins=3768, res=0.0432, offset=0.0, jitter=0.4),  # Oxford, azimuths off a regular step
    dict(rows=240, bins=2000, res=0.05, offset=0.5, dropped=(0, 7, 8, 120)),  # dropped rows (filled as the SDK does)
])
def test_the_graph_draws_the_sdk_image_on_any_geometry(geometry):
    _needs_exact_remap()
    profile = get_profile("cart-0.4")
    rng = np.random.default_rng(3)
    scan = _geometry_scan(rng, **geometry)
    want = polar_to_cartesian(scan, profile.resolution_m, profile.width_px, near_range_m=profile.near_range_m)
    got = _frontend_session(profile).run(None, sweep_feeds(scan))[0][0]
    assert want.max() > 0.1  # the image holds the sweep, so agreement means something
    # float32 positions (the SDK's maps are float64 maths): ~1e-4 of a bin on white-noise power, where a wrong
    # bin or row is off by ~0.1
    np.testing.assert_allclose(got, want, atol=1e-3)
    assert np.abs(got - want).mean() < 1e-5


def test_metadata_says_the_form_and_the_schema_holds_it(sweep_form_models):
    model = OnnxModel(sweep_form_models["cart-0.4"])
    info = model.info
    assert info.form == "sweep" and info.inputs == (*SWEEP_INPUTS, "prev_state")
    assert info.input_shape == (info.sweep_geometry["num_azimuths"], info.sweep_geometry["num_bins"])
    assert info.state_shape == OnnxModel(radar_odom.pretrained("cart-0.4")).info.state_shape
    # the graph draws the sweep as recorded: the options that draw it moved are refused in one line (issue 51)
    for option in ("deskew", "centre_yaw"):
        with pytest.raises(ConfigError, match="cannot be de-skewed or drawn turned"):
            RadarOdometer(model, **{option: True})
    odo = RadarOdometer(model)
    assert not odo.deskew and not odo.centre_yaw
    # a sweep form that would read another input is refused, with what to do
    meta = dict(model.session.get_modelmeta().custom_metadata_map)
    meta["radar_odom.inputs"] = '["cart", "azimuths_rad", "range_resolution_m", "range_offset_m", "prev_state"]'
    with pytest.raises(InvalidModelError, match="re-export"):
        type(info).from_metadata(meta, source="edited")


def test_only_a_cartesian_stream_graph_is_wrapped(tiny_polar_model, tiny_pair_model):
    pytest.importorskip("onnx", reason="onnx (the export extra) builds the sweep form")
    from radar_odom.errors import ExportError
    from radar_odom_export.sweep_form import wrap_stream_model

    for path in (tiny_polar_model, tiny_pair_model):
        with pytest.raises(ExportError, match="Cartesian stream-form"):
            wrap_stream_model(path)


# ------------------------------------------------------------------ the sweep is checked as the SDK path checks it
@pytest.fixture(scope="module")
def two_sweeps():
    return _drive(seed=5, frames=2)


def _garbage(feeds: dict, case: str) -> dict:
    """The issue's garbage sweeps (issue 51), made from clean ``feeds``."""
    g = dict(feeds)
    if case == "4000 azimuths":  # every row ten times, 0.09° apart: the SDK draws it, the bearing table cannot
        g["power"] = np.repeat(feeds["power"], 10, axis=0)
        g["azimuths_rad"] = ((np.arange(4000) + 0.5) * (2 * math.pi / 4000)).astype(np.float32)
    elif case == "degrees":
        g["azimuths_rad"] = np.degrees(feeds["azimuths_rad"]).astype(np.float32)
    elif case == "descending":
        g["power"], g["azimuths_rad"] = feeds["power"][::-1].copy(), feeds["azimuths_rad"][::-1].copy()
    elif case == "negative resolution":
        g["range_resolution_m"] = -feeds["range_resolution_m"]
    elif case == "one row":
        g["power"], g["azimuths_rad"] = feeds["power"][:1], feeds["azimuths_rad"][:1]
    return g


def _sdk_scan(feeds: dict, t0_us: int = 10**15) -> RadarScan:
    """The same arrays as the SDK path takes them, the first azimuth at ``t0_us``."""
    rows = np.asarray(feeds["azimuths_rad"]).shape[0]
    return RadarScan.from_arrays(t0_us + 62 * np.arange(rows), feeds["azimuths_rad"], feeds["power"],
                                 range_resolution_m=float(feeds["range_resolution_m"][0]),
                                 range_offset_m=float(feeds["range_offset_m"][0]))


# case -> (the error the SDK path and the sweep form raise, what the sweep form's message says)
GARBAGE = {
    "4000 azimuths": (radar_odom.errors.ModelMismatchError, r"4000 azimuths.*bearing table.*stream form"),
    "degrees": (radar_odom.errors.ScanFormatError, r"\[0, 2π\) radians, got \[0, 359.*degrees: give radians"),
    "descending": (radar_odom.errors.ScanFormatError, r"increase strictly.*they decrease: list the rows"),
    "negative resolution": (radar_odom.errors.ScanFormatError, r"range_resolution_m must be > 0 .*got -0.0432"),
    "one row": (radar_odom.errors.ScanFormatError, r"power must be a 2-D array .*at least 2 rows.*\(1, 3768\)"),
}


@pytest.mark.parametrize("case", sorted(GARBAGE))
def test_the_sweep_form_refuses_each_garbage_sweep_as_the_sdk_path_does(sweep_form_models, two_sweeps, case):
    """Issue 51: fed by hand (OnnxModel.run, GraphStep), the sweep form took each of these and returned finite
    poses (4000 azimuths: 6.7 cm from the SDK's). Now the same typed error as the SDK path, saying what to do."""
    from radar_odom.odometry.graph_step import GraphStep

    error, says = GARBAGE[case]
    model = OnnxModel(sweep_form_models["cart-0.4"], threads=1)
    clean = sweep_feeds(two_sweeps[0])
    state = model.run({**clean, "prev_state": np.zeros(model.info.state_shape, np.float32)})["state"]
    bad = _garbage(clean, case)
    with pytest.raises(error, match=says) as raised:
        model.run({**bad, "prev_state": state})
    assert "cart-0.4-sweep.onnx" in str(raised.value) and "\n" not in str(raised.value)
    with pytest.raises(error, match=says):
        GraphStep(model).match(bad, state)  # the odometer's own call of the graph
    if case == "4000 azimuths":
        # the SDK path draws it (any azimuth count); the sweep form's odometer refuses the sweep before its graph
        scan = _sdk_scan(bad, two_sweeps[1].timestamp_us)  # the next sweep's time
        sdk = RadarOdometer(radar_odom.pretrained("cart-0.4"), threads=1)
        assert sdk.step(two_sweeps[0]) is None and sdk.step(scan) is not None
        graph = RadarOdometer(model)
        graph.step(two_sweeps[0])
        with pytest.raises(error, match=says):
            graph.step(scan)
    else:  # the SDK path refuses the same arrays with the same type
        with pytest.raises(error):
            _sdk_scan(bad)


def test_sweep_feeds_of_an_unchecked_scan_are_refused_for_bare_onnxruntime(two_sweeps):
    """docs/sweep-form.md feeds bare onnxruntime with sweep_feeds(scan): a RadarScan built without from_arrays's
    checks (azimuths in degrees) is refused there, not handed to the graph."""
    import dataclasses

    scan = two_sweeps[0]
    degrees = dataclasses.replace(scan, azimuths_rad=np.degrees(scan.azimuths_rad).astype(np.float32))
    with pytest.raises(radar_odom.errors.ScanFormatError, match="degrees: give radians"):
        sweep_feeds(degrees)
    assert set(sweep_feeds(scan)) == set(SWEEP_INPUTS)


@pytest.mark.parametrize("geometry", [
    dict(rows=400, bins=3360, res=0.0596, offset=-0.31),  # Boreas
    dict(rows=400, bins=3768, res=0.0432, offset=0.0, jitter=0.4),  # Oxford, azimuths off a regular step
    dict(rows=240, bins=2000, res=0.05, offset=0.5, dropped=(0, 7, 8, 120)),  # dropped rows
    dict(rows=2048, bins=1000, res=0.1, offset=0.0),  # one row per table bin: the most the sweep form draws
])
def test_the_checks_pass_every_sweep_the_sweep_form_draws(geometry):
    import dataclasses

    from radar_odom.odometry.sweep_checks import check_sweep_feeds, check_sweep_geometry

    # the shipped model's metadata as its sweep form carries it (no onnx needed to wrap one)
    sweep_info = dataclasses.replace(OnnxModel(radar_odom.pretrained("cart-0.4"), threads=1).info, form="sweep")
    scan = _geometry_scan(np.random.default_rng(3), **geometry)
    check_sweep_feeds(sweep_feeds(scan), sweep_info)
    check_sweep_geometry(scan, sweep_info)


def test_the_bearing_table_takes_2048_rows_and_no_more():
    from radar_odom.model_file import SWEEP_TABLE_BINS
    from radar_odom.odometry.sweep_checks import sweep_form_table_problem

    def regular(n):
        return ((np.arange(n) + 0.5) * (2 * math.pi / n)).astype(np.float32)

    assert SWEEP_TABLE_BINS == 2048
    assert sweep_form_table_problem(regular(400)) is None and sweep_form_table_problem(regular(2048)) is None
    assert "2049 azimuths" in sweep_form_table_problem(regular(2049))
    pytest.importorskip("onnx", reason="the export side's constant")
    from radar_odom_export.sweep_form import TABLE_BINS

    assert TABLE_BINS == SWEEP_TABLE_BINS  # the graph's table is the one the runtime checks against


def test_openvino_checks_the_sweep_as_onnxruntime_does(sweep_form_models, two_sweeps):
    """OpenVinoModel.run takes the same feeds (docs/sweep-form.md): the same check, before OpenVINO is asked."""
    from radar_odom.runtimes import OpenVinoModel

    stub = OpenVinoModel.__new__(OpenVinoModel)  # no compile: the check comes before the infer request
    checked = OnnxModel(sweep_form_models["cart-0.4"], threads=1)
    stub.path, stub.info, stub.output_names = checked.path, checked.info, checked.output_names
    bad = _garbage(sweep_feeds(two_sweeps[0]), "degrees")
    with pytest.raises(radar_odom.errors.ScanFormatError, match="degrees: give radians"):
        stub.run({**bad, "prev_state": np.zeros(checked.info.state_shape, np.float32)})
