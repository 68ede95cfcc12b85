"""A ROS 2 node: radar sweeps in, ``nav_msgs/Odometry`` and TF ``odom`` → ``base_link`` out.

    source /opt/ros/humble/setup.bash && pip install radar-odom
    python examples/ros2_node.py --ros-args -p topic:=/Navtech/Polar -p model:=cart-0.4 \\
        -p range_resolution_m:=0.0432

Parameters: ``topic`` (radar topic), ``msg_type`` (``image`` = sensor_msgs/Image, ``compressed`` =
sensor_msgs/CompressedImage PNG, ``bscan`` = navtech_msgs/msg/RadarBScanMsg, which needs the
Navtech driver's ``navtech_msgs`` package sourced), ``model`` (shipped name or .onnx path),
``range_resolution_m``, ``sweep_period_s``, ``stamp`` (first | middle | last), ``odom_topic``,
``odom_frame``, ``base_frame``, ``publish_tf``. Frames follow REP-103/105 (see
`radar_odom.ros.msgs`); the pose covariance is the step's, in the odom frame's axes.

Not run in CI (no ROS there): everything but the rclpy calls is `radar_odom.ros.stream` and
`radar_odom.ros.msgs`, tested without ROS.
"""
from __future__ import annotations

MSG_TYPES = {
    "image": ("sensor_msgs.msg", "Image", "sensor_msgs/msg/Image"),
    "compressed": ("sensor_msgs.msg", "CompressedImage", "sensor_msgs/msg/CompressedImage"),
    "bscan": ("navtech_msgs.msg", "RadarBScanMsg", "navtech_msgs/msg/RadarBScanMsg"),
}


def fill_odometry(msg, fields, odom_frame: str, base_frame: str):
    """Copy `radar_odom.ros.msgs.OdometryFields` into a ``nav_msgs/msg/Odometry``."""
    from radar_odom.ros.msgs import split_ns

    msg.header.stamp.sec, msg.header.stamp.nanosec = split_ns(fields.stamp_ns)
    msg.header.frame_id, msg.child_frame_id = odom_frame, base_frame
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in fields.position_m)
    q.x, q.y, q.z, q.w = (float(v) for v in fields.orientation_xyzw)
    msg.pose.covariance = [float(v) for v in fields.pose_covariance]
    lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
    lin.x, lin.y, lin.z = (float(v) for v in fields.linear_mps)
    ang.x, ang.y, ang.z = (float(v) for v in fields.angular_rps)
    msg.twist.covariance = [float(v) for v in fields.twist_covariance]
    return msg


def fill_transform(tf, fields, odom_frame: str, base_frame: str):
    """Copy the pose of `OdometryFields` into a ``geometry_msgs/msg/TransformStamped``."""
    from radar_odom.ros.msgs import split_ns

    tf.header.stamp.sec, tf.header.stamp.nanosec = split_ns(fields.stamp_ns)
    tf.header.frame_id, tf.child_frame_id = odom_frame, base_frame
    t, r = tf.transform.translation, tf.transform.rotation
    t.x, t.y, t.z = (float(v) for v in fields.position_m)
    r.x, r.y, r.z, r.w = (float(v) for v in fields.orientation_xyzw)
    return tf


def main(args=None) -> None:
    import importlib

    import rclpy
    from geometry_msgs.msg import TransformStamped
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from tf2_ros import TransformBroadcaster

    from radar_odom import RadarOdometer
    from radar_odom.errors import RadarOdomError
    from radar_odom.model_zoo import resolve_model
    from radar_odom.ros.msgs import PolarImageGeometry
    from radar_odom.ros.stream import RosOdometryStream

    class RadarOdometryNode(Node):
        def __init__(self):
            super().__init__("radar_odom")
            topic = self.declare_parameter("topic", "/Navtech/Polar").value
            kind = self.declare_parameter("msg_type", "image").value
            model = self.declare_parameter("model", "cart-0.4").value
            geometry = PolarImageGeometry(
                range_resolution_m=float(self.declare_parameter("range_resolution_m", 0.0432).value),
                sweep_period_s=float(self.declare_parameter("sweep_period_s", 0.25).value),
                stamp=self.declare_parameter("stamp", "first").value)
            self.odom_frame = self.declare_parameter("odom_frame", "odom").value
            self.base_frame = self.declare_parameter("base_frame", "base_link").value
            publish_tf = bool(self.declare_parameter("publish_tf", True).value)
            odom_topic = self.declare_parameter("odom_topic", "/radar_odom/odometry").value
            module, cls, self.msgtype = MSG_TYPES[kind]
            msg_cls = getattr(importlib.import_module(module), cls)
            self.stream = RosOdometryStream(RadarOdometer(resolve_model(model)), geometry)
            self.pub = self.create_publisher(Odometry, odom_topic, 10)
            self.tf = TransformBroadcaster(self) if publish_tf else None
            self.create_subscription(msg_cls, topic, self.on_radar, 10)
            self.get_logger().info(f"radar-odom: {model} on {topic} ({self.msgtype}) -> {odom_topic}")

        def on_radar(self, msg):
            try:
                fields = self.stream.on_message(msg, self.msgtype)
            except RadarOdomError as exc:  # one bad sweep, or a jump in time: say so and go on
                self.stream.errors += 1
                self.get_logger().warning(f"sweep not used: {exc}")
                return
            if fields is None:
                return
            self.pub.publish(fill_odometry(Odometry(), fields, self.odom_frame, self.base_frame))
            if self.tf is not None:
                self.tf.sendTransform(fill_transform(TransformStamped(), fields, self.odom_frame, self.base_frame))

    rclpy.init(args=args)
    node = RadarOdometryNode()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
