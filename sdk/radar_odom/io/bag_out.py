"""Odometry into a ROS 2 bag (MCAP): one ``nav_msgs/Odometry`` per estimate, one ``tf2_msgs/TFMessage`` per sweep.

``radar-odom run ... --bag-out PATH`` calls `write_odometry_bag` after the run. ``PATH`` becomes a
ROS 2 bag folder (``PATH/metadata.yaml`` and ``PATH/<name>.mcap``), which ``ros2 bag play``,
``evo_traj bag2`` and rosbags read. Needs the ``ros`` extra (rosbags).

Messages (frames REP-103/105, `radar_odom.ros.msgs`): ``header.frame_id`` = ``odom_frame`` (the
first sweep's base frame), ``child_frame_id`` = ``base_frame``; pose = the sweep's absolute pose;
``pose.covariance`` = the step's 3×3 covariance in the (x, y, yaw) cells of the row-major 6×6
(indices 0, 1, 5, 6, 7, 11, 30, 31, 35), turned into the odom frame's axes, `UNOBSERVED_VARIANCE`
on z, roll, pitch (14, 21, 28); twist = the step over its time in the base frame (the
constant-velocity motion the prior carries on), its covariance the step's / dt². Each message is
stamped with the sweep's header stamp from the input bag (or its first-azimuth time). The TF
message holds ``odom_frame → base_frame`` at the same stamp (the first sweep: identity).
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from ..errors import MissingExtraError, OutputError
from ..ros.msgs import odometry_fields, split_ns, yaw_quaternion_xyzw

ODOM_TOPIC = "/radar_odom/odometry"
TF_TOPIC = "/tf"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"


def _rosbags_writer():
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise MissingExtraError("rosbags", "ros") from None
    return Writer, StoragePlugin, get_typestore(Stores.ROS2_HUMBLE)


def write_odometry_bag(path, timestamps_us, poses, estimates, stamps_ns=None, *, odom_topic: str = ODOM_TOPIC,
                       tf_topic: str = TF_TOPIC, odom_frame: str = ODOM_FRAME, base_frame: str = BASE_FRAME) -> Path:
    """Write a run's odometry to the ROS 2 MCAP bag ``path`` (a new folder, or, for a name ending in
    ``.mcap``, that one MCAP file); returns it.

    Args:
        timestamps_us: int64[N] the sweeps' first-azimuth times (`RadarOdometer.trajectory`).
        poses: float64[N, 3, 3] their absolute poses (Oxford frame, first = identity).
        estimates: the N − 1 `Estimate`s, estimate k for sweep k + 1.
        stamps_ns: int64[N] the stamps to write (the input messages' header stamps), or None
            for ``timestamps_us`` · 1000.
    Raises `OutputError` when ``path`` exists, `MissingExtraError` without rosbags.
    """
    from ..se2 import to_xyyaw

    Writer, StoragePlugin, store = _rosbags_writer()
    path = Path(path)
    if path.exists():
        raise OutputError(f"{path}: exists; --bag-out writes a new ROS 2 bag, give a new path")
    if path.suffix == ".mcap":
        # a name ending in .mcap asks for that one file, not a folder of that name around another
        # file: the bag is written as a folder beside it, then its MCAP file moved to the name
        folder = path.with_name(f".{path.name}.{os.getpid()}.bag")
        try:
            write_odometry_bag(folder, timestamps_us, poses, estimates, stamps_ns, odom_topic=odom_topic,
                               tf_topic=tf_topic, odom_frame=odom_frame, base_frame=base_frame)
            (folder / f"{folder.name}.mcap").replace(path)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        return path
    ts_us = np.asarray(timestamps_us, dtype=np.int64)
    n = len(ts_us)
    if len(estimates) != n - 1 or len(poses) != n:
        raise ValueError(f"{n} sweeps need {n - 1} estimates and {n} poses, got {len(estimates)} and {len(poses)}")
    stamps = ts_us * 1000 if stamps_ns is None else np.asarray(stamps_ns, dtype=np.int64)
    xyyaw = to_xyyaw(np.asarray(poses)) if n else np.zeros((0, 3))
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Point, Quat, Vec3 = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]
    Pose, Twist = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Twist"]
    PoseCov, TwistCov = T["geometry_msgs/msg/PoseWithCovariance"], T["geometry_msgs/msg/TwistWithCovariance"]
    Odometry, Transform = T["nav_msgs/msg/Odometry"], T["geometry_msgs/msg/Transform"]
    TfStamped, TFMessage = T["geometry_msgs/msg/TransformStamped"], T["tf2_msgs/msg/TFMessage"]

    def header(t_ns: int, frame: str):
        sec, nsec = split_ns(t_ns)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    def tf_msg(k: int):
        x, y, yaw = float(xyyaw[k, 0]), -float(xyyaw[k, 1]), -float(xyyaw[k, 2])  # REP-103
        q = yaw_quaternion_xyzw(yaw)
        tf = TfStamped(header=header(int(stamps[k]), odom_frame), child_frame_id=base_frame,
                       transform=Transform(translation=Vec3(x=x, y=y, z=0.0),
                                           rotation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])))
        return TFMessage(transforms=[tf])

    try:
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            c_odom = writer.add_connection(odom_topic, Odometry.__msgtype__, typestore=store)
            c_tf = writer.add_connection(tf_topic, TFMessage.__msgtype__, typestore=store)
            for k in range(n):
                t_ns = int(stamps[k])
                if k > 0:
                    est = estimates[k - 1]
                    f = odometry_fields(t_ns, poses[k], est.pose, est.covariance,
                                        (ts_us[k] - ts_us[k - 1]) * 1e-6, float(xyyaw[k - 1, 2]))
                    q = f.orientation_xyzw
                    odom = Odometry(
                        header=header(t_ns, odom_frame), child_frame_id=base_frame,
                        pose=PoseCov(pose=Pose(position=Point(x=f.position_m[0], y=f.position_m[1], z=0.0),
                                               orientation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])),
                                     covariance=np.asarray(f.pose_covariance, dtype=np.float64)),
                        twist=TwistCov(twist=Twist(linear=Vec3(x=f.linear_mps[0], y=f.linear_mps[1], z=0.0),
                                                   angular=Vec3(x=0.0, y=0.0, z=f.angular_rps[2])),
                                       covariance=np.asarray(f.twist_covariance, dtype=np.float64)))
                    writer.write(c_odom, t_ns, store.serialize_cdr(odom, Odometry.__msgtype__))
                writer.write(c_tf, t_ns, store.serialize_cdr(tf_msg(k), TFMessage.__msgtype__))
    except OSError as exc:
        raise OutputError(f"{path}: cannot write the bag ({exc.strerror or exc})") from None
    return path
