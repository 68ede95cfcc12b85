"""radar-odom: learned radar odometry (Masking by Moving, Barnes et al., CoRL 2019) at run time.

This package never imports torch. The public API:

    from radar_odom import load_scan, polar_to_cartesian, RadarOdometer
    odo = RadarOdometer(radar_odom.pretrained("cart-0.4"))
    est = odo.step(load_scan("seq/radar/1547131046353776.png"))   # None for the first sweep
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it; imported on first use so `import radar_odom` stays light
_LAZY = {
    "RadarScan": "scan",
    "GridProfile": "profiles",
    "get_profile": "profiles",
    "PROFILES": "profiles",
    "ScanFormatError": "errors",
    "SequenceError": "errors",
    "ModelMismatchError": "errors",
    "StreamError": "errors",
    "RadarOdomError": "errors",
    "polar_to_cartesian": "polar",
    "kitti_metrics": "evaluation.metrics",
    "load_scan": "io",
    "write_scan": "io",
    "read_sequence": "io",
    "RadarOdometer": "odometry.odometer",
    "iter_estimates": "odometry.pipeline",
    "match_sequence": "odometry.batch",
    "pretrained": "model_zoo",
    "pretrained_names": "model_zoo",
    "Estimate": "odometry.odometer",
    "MotionPriorConfig": "odometry.motion_prior",
    "OdometerConfig": "odometry.config",
    "ExternalOdometry": "odometry.motion_prior",
    "read_bag": "io.bag",
    "open_bag": "io.bag",
}

__all__ = sorted(_LAZY) + ["__version__"]


def __getattr__(name: str):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'radar_odom' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
