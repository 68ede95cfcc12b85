"""Open what a user calls a recording: a recording folder (`read_sequence`) or a ROS bag (`open_bag`).

The one home of that choice, below ``commands/`` so that both the command line (`radar-odom run`)
and the torch side (`radar_odom_export.adapt`) open recordings the same way."""
from __future__ import annotations

from pathlib import Path

from ..errors import ConfigError

BAG_SUFFIXES_SHOWN = ".bag, .mcap, .db3 or a ROS 2 bag folder with metadata.yaml"


def open_recording(source, topic: str | None = None, bag_geometry: dict | None = None, *, repair_stamps: bool = True):
    """A recording folder (`radar_odom.io.read_sequence`) or a ROS bag (`radar_odom.io.bag.open_bag`).

    ``topic`` and ``bag_geometry`` (`radar_odom.ros.msgs.PolarImageGeometry` fields) apply to bags only;
    given for a folder they are a `ConfigError`. A ``source`` that does not exist is a `SequenceError`
    saying so (not that it is "not a bag"), with the layouts a recording can have. ``repair_stamps``: False
    keeps the sweep stamps as recorded (`radar_odom.io.timebase`; `radar-odom run --keep-stamps`)."""
    from .bag import is_bag, open_bag
    from .sequence import read_sequence

    if is_bag(source):
        return open_bag(source, topic, repair_stamps=repair_stamps, **(bag_geometry or {}))
    if not Path(source).exists():  # said first: "--topic applies to bags; x.mcap is not one" misleads
        return read_sequence(source)  # SequenceError: it does not exist, and the layouts a recording can have
    if topic is not None:
        raise ConfigError(f"--topic {topic} applies to ROS bags ({BAG_SUFFIXES_SHOWN}); {source} is not one — "
                          "drop --topic to read it as a recording folder")
    if bag_geometry:
        raise ConfigError("the bag options (range resolution, sweep period, stamp, ...) apply to ROS bags only; "
                          f"{source} is not a bag")
    return read_sequence(source, repair_stamps=repair_stamps)
