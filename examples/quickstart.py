"""Quickstart: odometry with a shipped model over a recording (python examples/quickstart.py SEQ)."""
import sys
from pathlib import Path

import radar_odom
from radar_odom import RadarOdometer, load_scan

odo = RadarOdometer(radar_odom.pretrained("cart-0.4"))  # or RadarOdometer("model.onnx")
for png in sorted(Path(sys.argv[1], "radar").glob("*.png")):
    est = odo.step(load_scan(png))  # None for the first sweep
    if est is not None:
        print(est.timestamp_us, est.pose.round(3), est.covariance.diagonal().round(5), sorted(est.flags))
