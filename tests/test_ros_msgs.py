"""`radar_odom.ros.msgs`: ROS messages ↔ sweeps and odometry, tested without ROS or rosbags (plain
namespaces stand in for messages), so these run in the torch-free floors job too."""
import sys
from types import SimpleNamespace as NS

import cv2
import numpy as np
import pytest

from radar_odom.errors import MissingExtraError, ScanFormatError
from radar_odom.ros.msgs import (
    UNOBSERVED_VARIANCE,
    PolarImageGeometry,
    covariance_6x6,
    odometry_fields,
    scan_from_bscan_msg,
    scan_from_compressed_msg,
    scan_from_image_msg,
    scan_from_msg,
)
from radar_odom.se2 import se2

A, B = 40, 30
T0_NS = 1_547_131_050_856_549_000


def _stamp(t_ns):
    return NS(sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _image(pixels, encoding="mono8", pad=0, bigendian=False, t_ns=T0_NS):
    h, w = pixels.shape
    raw = pixels.astype(">u2" if bigendian else "<u2").tobytes() if pixels.dtype == np.uint16 else pixels.tobytes()
    row = w * pixels.dtype.itemsize
    rows = [raw[i * row:(i + 1) * row] + b"\0" * pad for i in range(h)]
    return NS(header=NS(stamp=_stamp(t_ns), frame_id="navtech"), height=h, width=w, encoding=encoding,
              is_bigendian=int(bigendian), step=row + pad, data=np.frombuffer(b"".join(rows), dtype=np.uint8))


def _pixels(seed=0, dtype=np.uint8):
    hi = 255 if dtype == np.uint8 else 65535
    return np.random.default_rng(seed).integers(0, hi + 1, size=(A, B)).astype(dtype)


def test_image_rows_are_azimuths_spread_over_the_sweep():
    px = _pixels()
    geo = PolarImageGeometry(range_resolution_m=0.5, sweep_period_s=0.2)
    scan = scan_from_image_msg(_image(px, pad=3), geo)
    np.testing.assert_array_equal(scan.power, px.astype(np.float32) / np.float32(255))
    assert scan.range_resolution_m == 0.5 and scan.num_azimuths == A
    np.testing.assert_allclose(scan.azimuths_rad, 2 * np.pi * np.arange(A) / A, atol=1e-6)
    # stamp = first azimuth; each next azimuth period / A later
    assert scan.timestamps_us[0] == T0_NS // 1000
    np.testing.assert_array_equal(np.diff(scan.timestamps_us), np.full(A - 1, 5000))
    mid = scan_from_image_msg(_image(px), PolarImageGeometry(sweep_period_s=0.2, stamp="middle"))
    assert mid.timestamps_us[0] == T0_NS // 1000 - 100_000


def test_mono16_big_endian_and_png_compressed_images_decode_to_the_same_power():
    px = _pixels(1, np.uint16)
    scan = scan_from_image_msg(_image(px, "mono16", bigendian=True))
    np.testing.assert_allclose(scan.power, px / 65535.0, atol=1e-7)
    ok, png = cv2.imencode(".png", px)
    comp = NS(header=NS(stamp=_stamp(T0_NS)), format="png", data=np.frombuffer(png.tobytes(), np.uint8))
    np.testing.assert_array_equal(scan_from_compressed_msg(comp).power, scan.power)
    assert scan_from_msg(comp, "sensor_msgs/CompressedImage").num_azimuths == A  # ROS 1 type name


def test_bad_messages_say_what_is_wrong():
    with pytest.raises(ScanFormatError, match="could not be decoded"):
        scan_from_compressed_msg(NS(header=NS(stamp=_stamp(T0_NS)), format="jpeg", data=b"not an image"))
    with pytest.raises(ScanFormatError, match="encoding 'rgb8'"):
        scan_from_image_msg(_image(_pixels(), encoding="rgb8"))
    short = _image(_pixels())
    short.data = short.data[:100]
    with pytest.raises(ScanFormatError, match="truncated"):
        scan_from_image_msg(short)
    with pytest.raises(ScanFormatError, match="not a radar sweep"):
        scan_from_msg(NS(), "std_msgs/msg/String")


def test_navtech_bscan_uses_its_own_encoder_angles_and_nanosecond_times():
    px = _pixels(2)
    enc = (np.arange(A) * (5600 // A) + 13).astype(np.uint16)
    ts_ns = (T0_NS + np.arange(A) * 6_250_000 + np.arange(A) % 3 * 1000).astype(np.uint64)
    ts_ns[5] = 0  # a row the driver never filled
    msg = NS(b_scan_img=_image(px, "8UC1"), encoder_values=enc, timestamps=ts_ns)
    scan = scan_from_bscan_msg(msg, PolarImageGeometry(range_resolution_m=0.0438))
    np.testing.assert_allclose(scan.azimuths_rad, 2 * np.pi * enc / 5600, atol=1e-6)
    assert scan.timestamps_us[0] == T0_NS // 1000 and scan.timestamps_us[7] == (int(ts_ns[7]) // 1000)
    assert not scan.valid[5] and scan.valid.sum() == A - 1 and scan.invalid_rows == (5,)
    assert scan.range_resolution_m == 0.0438
    with pytest.raises(ScanFormatError, match="encoder size"):
        scan_from_bscan_msg(msg, PolarImageGeometry(encoder_size=500))
    # stamps in µs where ns belong: the sweep would last a fraction of a millisecond (a trajectory dated 1970)
    msg.timestamps = (ts_ns // np.uint64(1000)).astype(np.uint64)
    with pytest.raises(ScanFormatError, match=r"span \d+ ns over \d+ rows.*not nanoseconds \(µs\?\)"):
        scan_from_bscan_msg(msg)
    msg.timestamps = ts_ns
    msg.encoder_values = enc[:-1]
    with pytest.raises(ScanFormatError, match="one per row"):
        scan_from_bscan_msg(msg)


def test_covariance_lands_in_the_x_y_yaw_cells_of_the_6x6():
    c = np.array([[1.0, 0.2, 0.3], [0.2, 2.0, 0.4], [0.3, 0.4, 3.0]])
    m = covariance_6x6(c).reshape(6, 6)
    flat = covariance_6x6(c)
    assert (flat[0], flat[1], flat[5], flat[6], flat[7], flat[11], flat[30], flat[31], flat[35]) == (
        1.0, 0.2, 0.3, 0.2, 2.0, 0.4, 0.3, 0.4, 3.0)
    assert flat[14] == flat[21] == flat[28] == UNOBSERVED_VARIANCE
    assert np.count_nonzero(m) == 9 + 3


def test_odometry_fields_are_rep103_with_the_step_covariance():
    # previous sweep at heading 90° right (Oxford yaw +π/2), step 1 m forward, 0.1 rad right
    prev = se2(2.0, 1.0, np.pi / 2)
    step = np.array([1.0, 0.0, 0.1])
    cov = np.diag([0.04, 0.01, 0.001])
    cov[0, 2] = cov[2, 0] = 0.002
    f = odometry_fields(10**18, prev @ se2(*step), step, cov, 0.25, np.pi / 2)
    # Oxford (x fwd, y right, z down) → REP-103 (y left, z up): the car went to y = 2 right → −2
    np.testing.assert_allclose(f.position_m, (2.0, -2.0, 0.0), atol=1e-12)
    yaw = 2 * np.arctan2(f.orientation_xyzw[2], f.orientation_xyzw[3])
    assert yaw == pytest.approx(-(np.pi / 2 + 0.1))
    np.testing.assert_allclose(f.linear_mps, (4.0, 0.0, 0.0))
    assert f.angular_rps[2] == pytest.approx(-0.4)
    p = f.pose_covariance.reshape(6, 6)[np.ix_((0, 1, 5), (0, 1, 5))]
    # the step's forward axis points along odom −y (REP-103 heading −90°): its variances swap, the
    # x–yaw term lands on y–yaw with both sign flips
    np.testing.assert_allclose(p, [[0.01, 0, 0], [0, 0.04, 0.002], [0, 0.002, 0.001]], atol=1e-12)
    t = f.twist_covariance.reshape(6, 6)[np.ix_((0, 1, 5), (0, 1, 5))]
    np.testing.assert_allclose(t, np.array([[0.04, 0, -0.002], [0, 0.01, 0], [-0.002, 0, 0.001]]) / 0.0625)


def test_bags_without_rosbags_name_the_extra(monkeypatch, tmp_path):
    from radar_odom.io.bag import open_bag
    from radar_odom.io.bag_out import write_odometry_bag

    monkeypatch.setitem(sys.modules, "rosbags", None)
    for mod in [m for m in sys.modules if m.startswith("rosbags.")]:
        monkeypatch.setitem(sys.modules, mod, None)
    (tmp_path / "x.mcap").write_bytes(b"")
    with pytest.raises(MissingExtraError, match=r'radar-odom\[ros\]'):
        open_bag(tmp_path / "x.mcap")
    with pytest.raises(MissingExtraError, match=r'radar-odom\[ros\]'):
        write_odometry_bag(tmp_path / "o.mcap", [0], np.eye(3)[None], [])


def _odometry_ns():
    """A stand-in for rclpy's nav_msgs/msg/Odometry and TransformStamped (the fields the node sets)."""
    def vec():
        return NS(x=0.0, y=0.0, z=0.0)

    def header():
        return NS(stamp=NS(sec=0, nanosec=0), frame_id="")

    odom = NS(header=header(), child_frame_id="",
              pose=NS(pose=NS(position=vec(), orientation=NS(x=0.0, y=0.0, z=0.0, w=1.0)), covariance=[0.0] * 36),
              twist=NS(twist=NS(linear=vec(), angular=vec()), covariance=[0.0] * 36))
    tf = NS(header=header(), child_frame_id="",
            transform=NS(translation=vec(), rotation=NS(x=0.0, y=0.0, z=0.0, w=1.0)))
    return odom, tf


def test_ros_stream_and_the_node_example_turn_radar_messages_into_odometry(cli_model):
    """What examples/ros2_node.py does with each message, without ROS: the same poses as stepping
    the sweeps directly, published in REP-103 with the step covariance."""

    from radar_odom import RadarOdometer
    from radar_odom.ros.stream import RosOdometryStream
    from radar_odom.sim.simulator import Simulator

    from fixtures import load_script

    node = load_script("examples/ros2_node.py")  # importable without rclpy: rclpy is imported in main()

    scans = [f.scan for f in Simulator(seed=21, frames=4, scenario="urban")]
    direct = RadarOdometer(cli_model, threads=1)
    stream = RosOdometryStream(RadarOdometer(cli_model, threads=1),
                               PolarImageGeometry(range_resolution_m=scans[0].range_resolution_m))
    published = []
    for scan in scans:
        px = np.round(scan.power * 255).astype(np.uint8)
        est = direct.step(scan)
        fields = stream.on_message(_image(px, t_ns=scan.timestamp_us * 1000), "sensor_msgs/msg/Image")
        assert (fields is None) == (est is None)
        if fields is None:
            continue
        odom, tf = _odometry_ns()
        node.fill_odometry(odom, fields, "odom", "base_link")
        node.fill_transform(tf, fields, "odom", "base_link")
        published.append((odom, tf))
        pose = direct.trajectory.poses[-1]
        assert odom.pose.pose.position.x == pytest.approx(pose[0, 2], abs=0.05)
        assert odom.pose.pose.position.y == pytest.approx(-pose[1, 2], abs=0.05)  # REP-103: y left
        assert odom.header.stamp.sec * 10**9 + odom.header.stamp.nanosec == scan.timestamp_us * 1000
        assert odom.pose.covariance[35] == pytest.approx(est.covariance[2, 2], rel=1e-3)
        assert odom.pose.covariance[14] == UNOBSERVED_VARIANCE
        assert (tf.transform.translation.x, tf.child_frame_id) == (odom.pose.pose.position.x, "base_link")
    assert len(published) == len(scans) - 1


def test_an_image_whose_size_fields_undercount_its_data_is_refused():
    """A height smaller than the data (a driver bug) would be read as a sweep of the first rows only."""
    from types import SimpleNamespace

    from radar_odom.errors import ScanFormatError
    from radar_odom.ros.msgs import image_pixels

    img = np.arange(40 * 10, dtype=np.uint8).reshape(40, 10)
    msg = SimpleNamespace(encoding="mono8", height=20, width=10, step=10, is_bigendian=0, data=img.reshape(-1))
    with pytest.raises(ScanFormatError, match=r"holds 400 bytes, more than height × step = 200"):
        image_pixels(msg, "m")
    msg.height = 40
    assert np.array_equal(image_pixels(msg, "m"), img)


def test_a_compressed_png_declaring_a_huge_image_is_refused_before_decoding():
    import struct
    import zlib
    from types import SimpleNamespace

    from radar_odom.errors import ScanFormatError
    from radar_odom.ros.msgs import compressed_pixels

    ihdr = struct.pack(">IIBBBBB", 65536, 65536, 8, 0, 0, 0, 0)
    head = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    msg = SimpleNamespace(format="png", data=np.frombuffer(head + b"\0" * 64, np.uint8))
    with pytest.raises(ScanFormatError, match=r"PNG declares 65536 × 65536 pixels .* refused without decoding"):
        compressed_pixels(msg, "compressed")
