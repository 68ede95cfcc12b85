"""Sweep geometry sanity and typed errors (issue 42, item 5): range bins no radar has for a model are refused
with the numbers, a sweep with another azimuth count mid-stream is flagged degenerate (not matched), stamps
before 1970 and absurd heading offsets are refused, and the SDK's bad-input errors are its own typed ones."""
import numpy as np
import pytest
from test_odometer import PERIOD_US, T0_US, drive, render_scan, world_points

from radar_odom.commands.cli import main
from radar_odom.errors import (
    ConfigError,
    GridError,
    InputTypeError,
    ModelMismatchError,
    RadarOdomError,
    ScanFormatError,
    StreamError,
)
from radar_odom.odometry.odometer import RadarOdometer
from radar_odom.odometry.stream_time import AZIMUTH_COUNT, MAX_AZIMUTH_COUNT_CHANGE, azimuth_count
from radar_odom.odometry.sweep_checks import MAX_RESOLUTION_RATIO, MIN_RANGE_OFFSET_M, implausible_range_bins
from radar_odom.scan import RadarScan

from fixtures import GEOM, TINY


@pytest.fixture(scope="module")
def odo_info(tiny_model):
    return RadarOdometer(tiny_model).info


def scan_with_bins(range_resolution_m, range_offset_m=0.0, num_bins=GEOM["num_bins"], t_us=T0_US):
    a = GEOM["num_azimuths"]
    power = np.random.default_rng(0).random((a, num_bins)).astype(np.float32)
    return RadarScan.from_arrays(t_us + np.arange(a) * (PERIOD_US // a), 2 * np.pi * np.arange(a) / a, power,
                                 range_resolution_m=range_resolution_m, range_offset_m=range_offset_m,
                                 source="odd-bins")


# ------------------------------------------------------------------------------------- range bins
@pytest.mark.parametrize("ratio", [1 / MAX_RESOLUTION_RATIO, 0.5, 1.0, 4.02, MAX_RESOLUTION_RATIO])
def test_range_resolutions_within_the_ratio_are_plausible(odo_info, ratio):
    assert odo_info.sweep_geometry["range_resolution_m"] == GEOM["range_resolution_m"]
    assert implausible_range_bins(ratio * GEOM["range_resolution_m"], 0.0, odo_info) is None


@pytest.mark.parametrize("ratio", [1 / (1.01 * MAX_RESOLUTION_RATIO), 1.01 * MAX_RESOLUTION_RATIO, 33.3, 1e6])
def test_range_resolutions_beyond_the_ratio_are_refused_with_the_numbers(odo_info, ratio):
    res = ratio * GEOM["range_resolution_m"]
    why = implausible_range_bins(res, 0.0, odo_info)
    assert why is not None and f"{res:g} m" in why and f"{GEOM['range_resolution_m']:g} m" in why


@pytest.mark.parametrize("offset, plausible", [
    (-0.31, True), (0.0, True), (MIN_RANGE_OFFSET_M, True), (0.49 * TINY.support_radius_m, True),
    (MIN_RANGE_OFFSET_M - 0.01, False), (-100.0, False), (0.5 * TINY.support_radius_m, False), (1e6, False),
])
def test_range_offsets(odo_info, offset, plausible):
    why = implausible_range_bins(GEOM["range_resolution_m"], offset, odo_info)
    assert (why is None) == plausible, why
    if not plausible:
        assert f"{offset:g} m" in why


@pytest.mark.parametrize("res, offset, said", [(10.0, 0.0, "10 m"), (GEOM["range_resolution_m"], 1e6, "1e+06 m"),
                                               (GEOM["range_resolution_m"], -100.0, "-100 m")])
def test_step_refuses_implausible_range_bins(tiny_model, res, offset, said):
    """`from_arrays(range_resolution_m=10)` and offsets of 1e6 / −100 m were matched into wrong steps unflagged."""
    odo = RadarOdometer(tiny_model)
    with pytest.raises(ModelMismatchError, match="odd-bins: ") as err:
        odo.step(scan_with_bins(res, offset))
    assert said in str(err.value) and "range_resolution_m=" in str(err.value)
    assert len(odo.trajectory) == 0


# ---------------------------------------------------------------------------------- azimuth count
def test_azimuth_count_is_the_streams_first_and_tolerates_a_few_rows():
    full = render_scan(world_points(), np.eye(3), T0_US)
    n = full.num_azimuths
    assert azimuth_count(full, None) == (n, None)
    assert azimuth_count(full, n) == (n, None)
    few = int(MAX_AZIMUTH_COUNT_CHANGE * n)
    geom = dict(GEOM, num_azimuths=n - few)
    assert azimuth_count(render_scan(world_points(), np.eye(3), T0_US, geom=geom), n) == (n, None)
    half = render_scan(world_points(), np.eye(3), T0_US, geom=dict(GEOM, num_azimuths=n // 2))
    assert azimuth_count(half, n) == (n, AZIMUTH_COUNT)
    assert azimuth_count(full, n // 2) == (n // 2, AZIMUTH_COUNT)


def test_a_sweep_with_half_its_azimuths_mid_stream_is_flagged_not_matched(tiny_model):
    rel = (1.6, 0.0, 0.05)
    scans = drive(rel, 5, seed=1)
    a = GEOM["num_azimuths"]
    half = scans[2]
    keep = np.arange(0, a, 2)  # every other row: the whole turn, half the rows
    scans[2] = RadarScan.from_arrays(half.timestamps_us[keep], half.azimuths_rad[keep], half.power[keep],
                                     range_resolution_m=half.range_resolution_m, source="half-sweep")
    odo = RadarOdometer(tiny_model)
    ests = [odo.step(s) for s in scans][1:]
    assert ests[1].degenerate and AZIMUTH_COUNT in ests[1].flags
    assert not ests[0].flags and not ests[3].degenerate  # the full sweeps around it are matched
    assert "bridged" in ests[2].flags  # the next one is matched across the flagged one
    odo.reset()  # a new stream takes its first sweep's count: half sweeps throughout are matched
    later = RadarScan.from_arrays(scans[2].timestamps_us + PERIOD_US, scans[2].azimuths_rad, scans[2].power,
                                  range_resolution_m=scans[2].range_resolution_m)
    assert odo.step(scans[2]) is None and AZIMUTH_COUNT not in odo.step(later).flags


# ------------------------------------------------------------------------------------------ stamps
def test_stamps_before_1970_are_refused():
    with pytest.raises(ScanFormatError, match="before 1970"):
        scan_with_bins(GEOM["range_resolution_m"], t_us=-10**9)
    assert scan_with_bins(GEOM["range_resolution_m"], t_us=0).timestamp_us == 0  # a recording without a clock


def test_skip_refuses_a_stamp_before_1970(tiny_model):
    with pytest.raises(StreamError, match="before 1970"):
        RadarOdometer(tiny_model).skip(-1)


# ------------------------------------------------------------------------------- heading offset (CLI)
@pytest.mark.parametrize("value", ["1e308", "361", "-720", "nan", "inf"])
def test_an_absurd_heading_offset_is_refused_before_reading(value, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "missing"), "-o", str(out), "--gt-heading-offset-deg", value]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("radar-odom run: error: --gt-heading-offset-deg") and len(err.splitlines()) == 1
    assert "does not exist" not in err  # refused before the recording is looked at
    assert not out.exists()


def test_a_heading_offset_on_a_bag_is_said_to_be_ignored(tmp_path, capsys, monkeypatch):
    import radar_odom.runs.run_sequence as run_mod

    bag = tmp_path / "drive.mcap"
    bag.write_bytes(b"")

    class Result:
        reference, reference_note, estimates, timestamps_us, metrics, step_errors = None, "", [], [], None, None
        num_degenerate, seconds_per_step, files, problems, throughput, skipped = 0, 0.0, {}, [], None, []

    monkeypatch.setattr(run_mod, "run_sequence", lambda *a, **k: Result())
    main(["run", str(bag), "-o", str(tmp_path / "out"), "--gt-heading-offset-deg", "3", "--no-plot"])
    err = capsys.readouterr().err
    assert "radar-odom run: warning: --gt-heading-offset-deg ignored: a ROS bag carries no GNSS/INS" in err


# ------------------------------------------------------------------------------------- typed errors
def test_the_sdks_bad_input_errors_are_typed_and_stay_what_they_were(tiny_model, tmp_path):
    from radar_odom import load_scan
    from radar_odom.evaluation.metrics import kitti_metrics
    from radar_odom.polar import polar_to_cartesian

    scan = scan_with_bins(GEOM["range_resolution_m"])
    with pytest.raises(ConfigError, match="resolution_m must be a finite number > 0") as err:
        polar_to_cartesian(scan, 0.0, 64)
    assert isinstance(err.value, ValueError)
    with pytest.raises(GridError, match="width_px=20000.*at most 4096") as err:
        polar_to_cartesian(scan, 0.4, 20000)
    assert isinstance(err.value, MemoryError) and isinstance(err.value, RadarOdomError)
    with pytest.raises(ConfigError, match="unknown radar format 'kitti'") as err:
        load_scan(tmp_path / "x.png", format="kitti")
    assert isinstance(err.value, ValueError)
    with pytest.raises(ConfigError) as err:
        kitti_metrics(np.zeros((3, 3, 3)), np.zeros((4, 3, 3)))
    assert isinstance(err.value, ValueError)
    with pytest.raises(InputTypeError, match="RadarScan.from_arrays") as err:
        RadarOdometer(tiny_model).step(scan.power)
    assert isinstance(err.value, TypeError)


@pytest.mark.parametrize("option, value, said", [("--range-resolution-m", "10", "10 m"),
                                                 ("--range-offset-m", "1e6", "1e+06 m"),
                                                 ("--range-offset-m", "-100", "-100 m")])
def test_a_bag_read_with_implausible_range_bins_is_refused_in_one_line(option, value, said, cli_model, tmp_path,
                                                                       capsys):
    """`--range-offset-m 1e6` ran to exit 0 with every estimate degenerate and nothing said; 10 m bins and a −100 m
    offset gave wrong steps unflagged."""
    pytest.importorskip("rosbags")
    from test_bags import write_bag

    from radar_odom import read_sequence
    from radar_odom.sim import write_drive

    drive = write_drive(tmp_path / "drive", seed=10042, frames=3, progress=False)
    seq = read_sequence(drive)
    bag = write_bag(tmp_path / "drive.mcap", [seq.scan(i) for i in range(len(seq))])
    out = tmp_path / "out"
    assert main(["run", str(bag), "--model", str(cli_model), "-o", str(out), "--no-plot", option, value]) == 1
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if "error" in ln.lower()]  # the rest is the progress bar
    assert "Traceback" not in err and len(errors) == 1, err
    assert errors[0].startswith("radar-odom run: error: ") and said in errors[0] and "--range-" in errors[0]
    assert not out.exists()


def test_a_sweep_whose_row_times_span_an_hour_is_refused():
    """Issue 51: a 1 h timestamp jump within one sweep was taken as a sweep (and `--sweep-period-s 10` as a bag's
    turn): a spinning radar turns in under 5 s, so both are refused in one typed line."""
    from radar_odom.errors import ConfigError, ScanFormatError
    from radar_odom.ros.msgs import PolarImageGeometry
    from radar_odom.scan import RadarScan

    rows = 400
    times = 1_547_131_050_000_000 + np.arange(rows) * 625
    times[200:] += 3_600_000_000  # an hour later, halfway round
    az = np.arange(rows) * 2 * np.pi / rows
    with pytest.raises(ScanFormatError, match="span 3.6e\\+03 s within one sweep"):
        RadarScan.from_arrays(times, az, np.zeros((rows, 64), np.float32))
    RadarScan.from_arrays(times[:200], az[:200], np.zeros((200, 64), np.float32))  # a quarter second is a sweep
    with pytest.raises(ConfigError, match="turns in under 5 s"):
        PolarImageGeometry(range_resolution_m=0.0432, sweep_period_s=10.0, stamp="last")
