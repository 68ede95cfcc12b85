"""ROS without ROS: message conversion (`msgs`: polar `Image`, PNG `CompressedImage`, Navtech
B-scan → `RadarScan`; estimates → `OdometryFields`) and a message-in, odometry-out stream
(`stream.RosOdometryStream`) that a node wraps. Reading and writing bags is in `radar_odom.io`."""
