"""Synthetic Navtech scanning-radar drives (numpy + OpenCV only; no torch).

    from radar_odom.sim import simulate_drive, write_drive, SimConfig, SCENARIOS
    for frame in simulate_drive(seed=3, frames=20, scenario="urban"):
        frame.scan, frame.static_label, frame.pose_mid, frame.pose_rel
    write_drive("drive/", seed=3, frames=20)   # Oxford layout + labels/

Modules: `config` (every parameter), `drive` (road and ego trajectory), `world` (static
scene), `traffic` (moving objects), `sensor` (rendering a sweep), `scenarios` (presets),
`simulator` (a drive, sweep by sweep), `writer` (Oxford layout on disk).
"""
from .config import (
    ArtefactConfig,
    DriveConfig,
    LabelConfig,
    Scenario,
    SensorConfig,
    SimConfig,
    SimConfigError,
    TrafficConfig,
    WorldConfig,
)
from .presets import SENSOR_PRESETS, get_sensor_preset, randomised_config
from .scenarios import SCENARIOS, get_scenario
from .simulator import SimFrame, Simulator, simulate_drive
from .writer import write_drive

# bumped whenever the same seed and config would give different sweeps (for caches keyed on it)
SIMULATOR_VERSION = 2

__all__ = [
    "ArtefactConfig",
    "DriveConfig",
    "LabelConfig",
    "SCENARIOS",
    "SENSOR_PRESETS",
    "SIMULATOR_VERSION",
    "Scenario",
    "SensorConfig",
    "SimConfig",
    "SimConfigError",
    "SimFrame",
    "Simulator",
    "TrafficConfig",
    "WorldConfig",
    "get_scenario",
    "get_sensor_preset",
    "randomised_config",
    "simulate_drive",
    "write_drive",
]
