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
    "kitti_metrics": "metrics",
    "load_scan": "formats",
    "write_scan": "formats",
    "read_sequence": "formats",
    "RadarOdometer": "odometer",
    "iter_estimates": "pipeline",
    "match_sequence": "batch",
    "pretrained": "model_zoo",
    "pretrained_names": "model_zoo",
    "Estimate": "odometer",
    "MotionPriorConfig": "motion_prior",
    "ExternalOdometry": "motion_prior",
    "read_bag": "formats.bag",
    "open_bag": "formats.bag",
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
