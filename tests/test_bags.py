"""ROS bags in and out (`radar_odom.io.bag`, `radar_odom.io.bag_out`, ``radar-odom run BAG``).

Bags are written here with rosbags from simulated sweeps and from the real Oxford sweeps (in
tmp_path; the real sweeps never enter the repository), then run like the PNG folders they came
from. The ``ros`` extra (rosbags) is needed; without it (the floors job) this module is skipped.
"""
from pathlib import Path

import numpy as np
import pytest

rosbags = pytest.importorskip("rosbags", reason="the ros extra (rosbags) is not installed")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from radar_odom.commands.cli import main  # noqa: E402
from radar_odom.errors import ScanFormatError, SequenceError  # noqa: E402
from radar_odom.io import load_scan, read_sequence  # noqa: E402
from radar_odom.io.bag import open_bag, read_bag  # noqa: E402
from radar_odom.ros.msgs import NAVTECH_BSCAN_MSGDEF, NAVTECH_BSCAN_MSGTYPE, UNOBSERVED_VARIANCE  # noqa: E402
from radar_odom.runs.run_sequence import read_estimates_csv, run_sequence  # noqa: E402

FRAMES = 5
OXFORD_PAIR = "oxford-2019-01-10-14-36-48"
IMAGE = "sensor_msgs/msg/Image"


# ------------------------------------------------------------------------------ writing test bags
def _store(ros1=False):
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(NAVTECH_BSCAN_MSGDEF, NAVTECH_BSCAN_MSGTYPE))
    return store


def _image_msg(store, scan, t_ns, ros1=False):
    T = store.types
    px = np.round(scan.power * 255).astype(np.uint8)
    stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    head = T["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=stamp, frame_id="navtech")
    return T[IMAGE](header=head, height=px.shape[0], width=px.shape[1], encoding="mono8", is_bigendian=0,
                    step=px.shape[1], data=px.reshape(-1))


def _bscan_msg(store, scan, ros1=False):
    img = _image_msg(store, scan, int(scan.timestamps_us[len(scan.timestamps_us) // 2]) * 1000, ros1)
    return store.types[NAVTECH_BSCAN_MSGTYPE](
        b_scan_img=img, encoder_values=scan.encoder_counts.astype(np.uint16),
        timestamps=scan.timestamps_us.astype(np.uint64) * 1000)


def write_bag(path, scans, topic="/Navtech/Polar", kind="image", extra=()):
    """A bag of ``scans``: ROS 1 for a ``.bag`` path, else ROS 2 (``.mcap``: MCAP, else sqlite3).
    ``kind``: "image" (stamp = first azimuth) or "bscan"; ``extra``: (topic, msgtype, [messages])."""
    path = Path(path)
    ros1 = path.suffix == ".bag"
    store = _store(ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if path.suffix == ".mcap" else StoragePlugin.SQLITE3
        writer, ser = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    msgtype = IMAGE if kind == "image" else NAVTECH_BSCAN_MSGTYPE
    with writer:
        conn = writer.add_connection(topic, msgtype, typestore=store)
        for scan in scans:
            t_ns = scan.timestamp_us * 1000
            msg = _image_msg(store, scan, t_ns, ros1) if kind == "image" else _bscan_msg(store, scan, ros1)
            writer.write(conn, t_ns, ser(msg, msgtype))
        for other_topic, other_type, msgs in extra:
            c = writer.add_connection(other_topic, other_type, typestore=store)
            for t_ns, msg in msgs:
                writer.write(c, t_ns, ser(msg, other_type))
    return path


def read_odometry(path):
    """[(log time ns, message)] of the nav_msgs/Odometry and TF in a bag, read back with rosbags."""
    odom, tf = [], []
    with AnyReader([Path(path)]) as reader:
        for conn, t_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            (odom if conn.msgtype == "nav_msgs/msg/Odometry" else tf).append((t_ns, msg))
    return odom, tf


# ------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("sim") / "drive", seed=12, frames=FRAMES, progress=False)


@pytest.fixture(scope="module")
def drive_scans(drive):
    seq = read_sequence(drive)
    return [seq.scan(i) for i in range(len(seq))]


@pytest.fixture(scope="module")
def png_run(drive, cli_model, tmp_path_factory):
    return run_sequence(drive, cli_model, tmp_path_factory.mktemp("png"), show_progress=False, plot=False)


def _poses(result):
    return np.array([e.pose for e in result.estimates])


# ------------------------------------------------------------------------------ bags in
@pytest.mark.parametrize("name", ["drive.bag", "drive.mcap", "drive_sqlite"])
def test_navtech_bscan_bags_give_the_png_runs_estimates(drive_scans, png_run, cli_model, tmp_path, name):
    """The B-scan carries the driver's own azimuth times and encoder angles: the same sweeps exactly."""
    bag = write_bag(tmp_path / name, drive_scans, topic="/radar_data/b_scan_msg", kind="bscan")
    scans = list(read_bag(bag))  # the only radar topic
    for a, b in zip(scans, drive_scans):
        np.testing.assert_array_equal(a.timestamps_us, b.timestamps_us)
        np.testing.assert_array_equal(a.power, b.power)
        np.testing.assert_allclose(a.azimuths_rad, b.azimuths_rad, atol=1e-6)
    res = run_sequence(bag, cli_model, tmp_path / "out", show_progress=False, plot=False)
    np.testing.assert_array_equal(res.timestamps_us, png_run.timestamps_us)
    np.testing.assert_allclose(_poses(res), _poses(png_run), atol=1e-5)


def test_image_bag_gives_the_png_runs_estimates_within_the_azimuth_time_approximation(
        drive_scans, png_run, cli_model, tmp_path):
    """A sensor_msgs/Image knows no azimuth times or angles: they are spread evenly over the
    sweep (`PolarImageGeometry`). The simulated sensor's are even too, so the estimates come out
    the same here (measured: identical); the bound checked is the issue's 5 cm / 0.05°."""
    bag = write_bag(tmp_path / "drive.bag", drive_scans)
    res = run_sequence(bag, cli_model, tmp_path / "out", show_progress=False, plot=False, topic="/Navtech/Polar")
    assert res.timestamps_us[0] == png_run.timestamps_us[0] and len(res.estimates) == FRAMES - 1
    d = np.abs(_poses(res) - _poses(png_run))
    assert d[:, :2].max() < 0.05 and np.degrees(d[:, 2].max()) < 0.05, d


def test_missing_topic_lists_the_topics_and_wrong_types_are_named(drive_scans, tmp_path):
    store = _store()
    T = store.types
    status = [(drive_scans[0].timestamp_us * 1000, T["std_msgs/msg/String"](data="ok"))]
    bag = write_bag(tmp_path / "two.mcap", drive_scans[:2], extra=[("/status", "std_msgs/msg/String", status)])
    with pytest.raises(SequenceError, match=r"no topic '/radar'.*/Navtech/Polar \(sensor_msgs/msg/Image\).*/status"):
        open_bag(bag, "/radar")
    with pytest.raises(SequenceError, match=r"/status carries std_msgs/msg/String, not a radar sweep"):
        open_bag(bag, "/status")
    assert len(open_bag(bag)) == 2  # the only radar topic is found without --topic


def test_truncated_bag_says_how_to_repair_it(drive_scans, tmp_path):
    bag = write_bag(tmp_path / "cut.bag", drive_scans[:3])
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 2])
    with pytest.raises(SequenceError, match="reindex"):
        open_bag(bag)


def test_undecodable_compressed_sweep_is_skipped_and_reported(drive_scans, cli_model, tmp_path, capsys):
    store = _store()
    T = store.types
    msgs = []
    import cv2

    for k, scan in enumerate(drive_scans):
        t_ns = scan.timestamp_us * 1000
        png = cv2.imencode(".png", np.round(scan.power * 255).astype(np.uint8))[1].tobytes()
        data = b"garbage" if k == 2 else png
        stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        msgs.append((t_ns, T["sensor_msgs/msg/CompressedImage"](
            header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="r"), format="png",
            data=np.frombuffer(data, np.uint8))))
    bag = write_bag(tmp_path / "comp.mcap", [], topic="/unused",
                    extra=[("/radar/compressed", "sensor_msgs/msg/CompressedImage", msgs)])
    with pytest.raises(ScanFormatError, match="could not be decoded"):
        list(read_bag(bag, "/radar/compressed"))
    code = main(["run", str(bag), "--topic", "/radar/compressed", "--model", str(cli_model),
                 "-o", str(tmp_path / "o"), "--no-plot"])
    assert code == 3
    err = capsys.readouterr().err
    assert "skipped sweep 2 (unreadable)" in err and "could not be decoded" in err


# ------------------------------------------------------------------------------ odometry out
def test_bag_out_holds_one_odometry_per_estimate_with_its_covariance(drive_scans, png_run, cli_model, tmp_path):
    bag = write_bag(tmp_path / "in.mcap", drive_scans, kind="bscan")
    out = tmp_path / "odom.mcap"
    res = run_sequence(bag, cli_model, tmp_path / "o", show_progress=False, plot=False, bag_out=out)
    assert res.files["bag"] == out and out.is_file()  # a name ending in .mcap is that file, not a folder
    odom, tf = read_odometry(out)
    assert len(odom) == len(res.estimates) == FRAMES - 1 and len(tf) == FRAMES
    seq = open_bag(bag)
    for k, (t_ns, msg) in enumerate(odom):
        est = res.estimates[k]
        # stamped with the input message's header stamp (the B-scan's: its middle azimuth)
        assert t_ns == seq.stamps_ns[k + 1] == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert msg.header.frame_id == "odom" and msg.child_frame_id == "base_link"
        c = msg.pose.covariance.reshape(6, 6)
        assert c[2, 2] == c[3, 3] == c[4, 4] == UNOBSERVED_VARIANCE
        # x, y, yaw cells: the step covariance, REP-103 signs, turned by the previous heading
        cov3 = c[np.ix_((0, 1, 5), (0, 1, 5))]
        assert np.trace(cov3[:2, :2]) == pytest.approx(np.trace(est.covariance[:2, :2]), rel=1e-9)
        assert cov3[2, 2] == pytest.approx(est.covariance[2, 2], rel=1e-12)
        if k == 0:  # previous heading 0: only the sign flips of y and yaw
            j = np.diag([1.0, -1.0, -1.0])
            np.testing.assert_allclose(cov3, j @ est.covariance @ j, rtol=1e-12, atol=1e-18)
        dt = (res.timestamps_us[k + 1] - res.timestamps_us[k]) * 1e-6
        assert msg.twist.twist.linear.x == pytest.approx(est.pose[0] / dt)
        assert msg.twist.twist.linear.y == pytest.approx(-est.pose[1] / dt)
        assert msg.twist.twist.angular.z == pytest.approx(-est.pose[2] / dt)
        x, y = msg.pose.pose.position.x, msg.pose.pose.position.y
        np.testing.assert_allclose([x, -y], res.poses[k + 1][:2, 2], atol=1e-9)
        tr = tf[k + 1][1].transforms[0]
        assert (tr.transform.translation.x, tr.transform.translation.y) == pytest.approx((x, y))
    assert (tf[0][1].transforms[0].transform.rotation.w, tf[0][1].transforms[0].transform.translation.x) == (1.0, 0.0)


def test_bag_out_refuses_an_existing_path(drive, cli_model, tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    assert main(["run", str(drive), "--model", str(cli_model), "-o", str(tmp_path / "o"), "--no-plot",
                 "--bag-out", str(tmp_path / "taken")]) == 1
    assert "exists" in capsys.readouterr().err


# ------------------------------------------------------------------------------ real Oxford sweeps
@pytest.mark.real
def test_real_oxford_mcap_runs_like_the_pngs(real_data_dir, tmp_path, capsys):
    """The issue's check: the real Oxford pair as sensor_msgs/Image on /Navtech/Polar in a ROS 2
    MCAP bag, run with the defaults and --bag-out, against the PNG run with the shipped model.
    Measured: 1.2 cm in x, 0.6 cm in y, 0° in yaw (the image's row 0 is taken at 0 rad; Oxford's
    first encoder count is 13/5600 = 0.84°); with --azimuth-offset-rad 0.014586 the two agree to 1e-6 m."""
    seq_dir = real_data_dir / OXFORD_PAIR
    scans = [load_scan(p) for p in sorted((seq_dir / "radar").glob("*.png"))]
    bag = write_bag(tmp_path / "oxford.mcap", scans)
    out_bag, out_png, odom_bag = tmp_path / "bag", tmp_path / "png", tmp_path / "odom.mcap"
    assert main(["run", str(bag), "--topic", "/Navtech/Polar", "--bag-out", str(odom_bag), "-o", str(out_bag),
                 "--no-plot"]) == 0
    assert "model: cart-0.4" in capsys.readouterr().out
    assert main(["run", str(seq_dir), "-o", str(out_png), "--no-plot"]) == 0
    ts_b, pose_b, cov_b, _ = read_estimates_csv(out_bag / "estimates.csv")
    ts_p, pose_p, _, _ = read_estimates_csv(out_png / "estimates.csv")
    np.testing.assert_array_equal(ts_b, ts_p)
    d = np.abs(pose_b - pose_p)
    assert d[:, :2].max() < 0.05 and np.degrees(d[:, 2]).max() < 0.05, d
    odom, _ = read_odometry(odom_bag)
    assert len(odom) == len(pose_b) == 1
    c = odom[0][1].pose.covariance
    j = np.diag([1.0, -1.0, -1.0])
    cells = (j @ cov_b[0] @ j)
    assert (c[0], c[7], c[35], c[1], c[5], c[11]) == pytest.approx(
        (cells[0, 0], cells[1, 1], cells[2, 2], cells[0, 1], cells[0, 2], cells[1, 2]), rel=1e-6, abs=1e-15)


def test_an_unknown_bag_option_is_named_with_the_valid_ones(tmp_path):
    """open_bag(p, range_resolutoin_m=0.1) raised PolarImageGeometry's raw TypeError."""
    from radar_odom.errors import ConfigError
    from radar_odom.io.bag import open_bag

    with pytest.raises(ConfigError, match=r"unknown bag option 'range_resolutoin_m'; open_bag takes "
                                          r"range_resolution_m, .*sweep_period_s"):
        open_bag(tmp_path / "b.mcap", range_resolutoin_m=0.1)


def _lattice_scans(stamps_us, azimuths=40, bins=64):
    """Small sweeps (uniform azimuths over 0.25 s) whose first azimuths are at ``stamps_us``."""
    from radar_odom.scan import RadarScan

    rng = np.random.default_rng(0)
    az = np.linspace(0, 2 * np.pi, azimuths, endpoint=False)
    return [RadarScan.from_arrays(int(t) + np.arange(azimuths) * (250_000 // azimuths), az,
                                  rng.random((azimuths, bins)).astype(np.float32)) for t in stamps_us]


def test_a_bags_late_host_stamps_are_put_on_the_recordings_time_base(tmp_path):
    from radar_odom.errors import StampWarning

    truth = 1_600_000_000_000_000 + 250_000 * np.arange(30)
    recorded = truth.copy()
    recorded[10:14] += [230_000, 180_000, 120_000, 60_000]  # a late run and its catch-up, like RADIATE's host
    bag = write_bag(tmp_path / "late.mcap", _lattice_scans(recorded))
    with pytest.warns(StampWarning, match="late"):
        seq = open_bag(bag)
    np.testing.assert_allclose(seq.timestamps_us, truth, atol=3_000)  # on the 250 ms lattice again
    assert seq.time_base is not None and seq.time_base.period_s == pytest.approx(0.25, abs=1e-3)
    assert set(seq.time_base.late.tolist()) >= {10, 11, 12}
    scan = seq.scan(10)  # the sweep's own azimuth times move with it
    assert abs(int(scan.timestamps_us[0]) - int(truth[10])) <= 3_000
    np.testing.assert_array_equal(seq.stamps_ns, recorded * 1000)  # header stamps stay as recorded (bag out)
    raw = open_bag(bag, repair_stamps=False)
    np.testing.assert_array_equal(raw.timestamps_us, recorded)
    assert raw.time_base is None and int(raw.scan(10).timestamps_us[0]) == int(recorded[10])


def test_a_bag_with_stale_stamps_keeps_them_for_the_run_to_skip(tmp_path):
    recorded = 1_600_000_000_000_000 + 250_000 * np.arange(8)
    recorded[5] = recorded[4]  # a duplicate stamp: iter_estimates skips it as stale, one by one
    seq = open_bag(write_bag(tmp_path / "stale.mcap", _lattice_scans(recorded)))
    assert seq.time_base is None
    np.testing.assert_array_equal(seq.timestamps_us, recorded)
