"""`RosOdometryStream`: radar messages in, `OdometryFields` out — the whole of a ROS node but the ROS.

``examples/ros2_node.py`` subscribes to a radar topic and hands each message here; what comes back
is copied into a ``nav_msgs/Odometry`` and a TF. Kept in the package (no rclpy, no rosbags) so it
is tested without ROS.
"""
from __future__ import annotations

import numpy as np

from ..errors import RadarOdomError
from .msgs import OdometryFields, PolarImageGeometry, odometry_fields, scan_from_msg


class RosOdometryStream:
    """Steps a `RadarOdometer` on ROS radar messages.

    Args:
        odometer: the `RadarOdometer` (its motion prior, threads, ... as configured).
        geometry: `PolarImageGeometry` of Image messages (range resolution, sweep period, ...).
    """

    def __init__(self, odometer, geometry: PolarImageGeometry | None = None):
        self.odometer = odometer
        self.geometry = geometry or PolarImageGeometry()
        self.errors = 0  # messages that could not be used (logged by the caller)

    def on_message(self, msg, msgtype: str, stamp_ns: int | None = None) -> OdometryFields | None:
        """One radar message → its `OdometryFields` (None for the first sweep of a stream).

        ``stamp_ns``: the stamp to publish with (default: the message's header stamp).
        Raises the SDK's typed errors (`ScanFormatError`, `StreamError`, ...); a caller that keeps
        running counts them in ``errors`` and goes on.
        """
        from .msgs import stamp_ns as header_ns

        scan = scan_from_msg(msg, msgtype, self.geometry, source=f"{msgtype} message")
        traj_before = self.odometer.trajectory
        est = self.odometer.step(scan)
        if est is None:
            return None
        traj = self.odometer.trajectory
        if len(traj) < 2 or len(traj_before) < 1:
            raise RadarOdomError("the odometer's trajectory did not grow with the estimate")
        prev = traj.poses[-2]
        prev_yaw = float(np.arctan2(prev[1, 0], prev[0, 0]))
        dt_s = (int(traj.timestamps_us[-1]) - int(traj.timestamps_us[-2])) * 1e-6
        if stamp_ns is None:
            head = msg.b_scan_img.header if hasattr(msg, "b_scan_img") else msg.header
            stamp_ns = header_ns(head.stamp)
        return odometry_fields(stamp_ns, traj.poses[-1], est.pose, est.covariance, dt_s, prev_yaw)

    def reset(self) -> None:
        """Start a new stream (e.g. after the bag loops or the radar restarts)."""
        self.odometer.reset()
