"""Radar sweeps from ROS bags: ROS 1 ``.bag``, ROS 2 bag folders (sqlite3 or MCAP) and ``.mcap`` files.

Read with the pure-Python ``rosbags`` library (the ``ros`` extra: ``pip install "radar-odom[ros]"``;
no ROS installation needed). One topic of one of the message types `radar_odom.ros.msgs` converts
(``sensor_msgs/Image`` polar sweeps, PNG ``sensor_msgs/CompressedImage``, the Navtech driver's
``navtech_msgs/msg/RadarBScanMsg``, registered here as a custom type for bags that do not carry
its definition) becomes a `BagSequence`: a `radar_odom.io.Sequence` whose sweeps are decoded
when asked for, in the bag's order, so ``radar-odom run BAG --topic T`` and
`radar_odom.iter_estimates` treat it like a recording folder.

    from radar_odom import read_bag
    for scan in read_bag("drive.mcap", topic="/Navtech/Polar", range_resolution_m=0.0432):
        ...

Opening reads the bag once (each message's header stamp), so a truncated or corrupt bag fails
there, with a `SequenceError` that says how to repair it; a message that cannot be decoded later
(a compressed image OpenCV cannot read) is one sweep's `ScanFormatError`, which ``run`` skips.
"""
from __future__ import annotations

import threading
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import MissingExtraError, ScanFormatError, SequenceError, StampWarning
from ..ros.msgs import (
    NAVTECH_BSCAN_MSGDEF,
    NAVTECH_BSCAN_MSGTYPE,
    RADAR_MSGTYPES,
    PolarImageGeometry,
    msgtype_name,
    scan_from_msg,
    stamp_ns,
)
from .sequence import Sequence

BAG_SUFFIXES = (".bag", ".mcap", ".db3")
BAG_FORMAT = "bag"
_REPAIR = ("a truncated bag (a recorder that was killed) can often be repaired with `rosbag reindex` (ROS 1) "
           "or `ros2 bag reindex` (ROS 2)")


def is_bag(path) -> bool:
    """True for a ``.bag`` / ``.mcap`` / ``.db3`` file or a ROS 2 bag folder (``metadata.yaml`` inside)."""
    p = Path(path)
    if p.is_file():
        return p.suffix.lower() in BAG_SUFFIXES
    return p.is_dir() and (p / "metadata.yaml").is_file()


def rosbags_modules():
    """(AnyReader, typestore factory) from rosbags, or `MissingExtraError` naming the ``ros`` extra."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError:
        raise MissingExtraError("rosbags", "ros") from None

    def typestore():
        store = get_typestore(Stores.ROS2_HUMBLE)
        store.register(get_types_from_msg(NAVTECH_BSCAN_MSGDEF, NAVTECH_BSCAN_MSGTYPE))
        return store

    return AnyReader, typestore


def _open_reader(path: Path):
    AnyReader, typestore = rosbags_modules()
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # rosbags raises its own error classes and, on a cut file, struct/OS errors
        raise SequenceError(f"{path}: cannot open the bag ({type(exc).__name__}: {exc}); {_REPAIR}") from None
    return reader


def _topics_text(reader) -> str:
    rows = sorted({(c.topic, c.msgtype) for c in reader.connections})
    return ", ".join(f"{t} ({m})" for t, m in rows) or "none"


def _first_azimuth_us(msg, msgtype: str, geometry: PolarImageGeometry) -> tuple[int, int]:
    """(header stamp ns, first azimuth's time µs) of a radar message, without decoding its pixels."""
    if msgtype_name(msgtype) == NAVTECH_BSCAN_MSGTYPE:
        head_ns = stamp_ns(msg.b_scan_img.header.stamp)
        ts = np.asarray(msg.timestamps).astype(np.uint64)
        ts = ts[ts > 0]
        return head_ns, int(ts[0] // 1000) if ts.size else head_ns // 1000
    head_ns = stamp_ns(msg.header.stamp)
    period_us = geometry.sweep_period_s * 1e6
    a = int(getattr(msg, "height", 0)) or 400  # CompressedImage: rows unknown before decoding
    shift = {"first": 0.0, "middle": period_us / 2.0, "last": period_us * (a - 1) / a}[geometry.stamp]
    return head_ns, int(round(head_ns / 1000.0 - shift))


def fit_bag_time_base(path, first_azimuth_us, period_s: float):
    """The recording's time base (`radar_odom.io.timebase`) fitted on a bag's sweep stamps, or None where
    they cannot carry one: fewer than `timebase.MIN_SWEEPS`, or not increasing (stale or duplicate stamps,
    which `iter_estimates` skips one by one as it reads). A driver stamps each message on its host, late
    by its load like RADIATE's recorder: one fit gives the reader, the gaps and de-skew the same times.
    A `StampWarning` says what was moved."""
    from .timebase import MIN_SWEEPS, fit_time_base

    stamps = np.asarray(first_azimuth_us, dtype=np.int64)
    if stamps.size < MIN_SWEEPS or not np.all(np.diff(stamps) > 0):
        return None
    try:
        base = fit_time_base(stamps, period_hint_us=float(period_s) * 1e6)
    except SequenceError as exc:  # not a spinning sensor's rhythm: the stamps are kept as recorded
        warnings.warn(f"{path}: sweep stamps kept as recorded ({exc})", StampWarning, stacklevel=3)
        return None
    if base.summary():
        warnings.warn(f"{path}: {base.summary()}; to keep them as recorded, open the bag with repair_stamps=False "
                      "(radar-odom run --keep-stamps)",
                      StampWarning, stacklevel=3)
    return base


class BagSequence(Sequence):
    """One radar topic of a bag as a `Sequence` (format ``"bag"``; no ground truth).

    ``timestamps_us`` int64[N]: each sweep's first-azimuth time (µs), on the recording's time base
    (``time_base``, `fit_bag_time_base`; as recorded with ``repair_stamps=False`` or where no base fits);
    ``stamps_ns`` int64[N]: the messages' header stamps as recorded (ns), which `radar_odom.io.bag_out`
    stamps the odometry with; ``topic``,
    ``msgtype``, ``geometry`` (`PolarImageGeometry`). ``paths[i]`` names the message
    (``BAG[TOPIC #i]``) in errors. `scan` decodes message ``i``, reading the bag forward from the
    last one asked for (in order, as `iter_estimates` asks, each message is read once).
    """

    def __init__(self, path, topic: str | None = None, geometry: PolarImageGeometry | None = None,
                 repair_stamps: bool = True):
        path = Path(path)
        if not path.exists():
            raise SequenceError(f"{path}: no such bag file or folder")
        self.geometry = geometry or PolarImageGeometry()
        reader = _open_reader(path)
        try:
            radar = [c for c in reader.connections if msgtype_name(c.msgtype) in RADAR_MSGTYPES]
            if topic is None:
                topics = sorted({c.topic for c in radar})
                if len(topics) != 1:
                    why = "no radar topic" if not topics else f"{len(topics)} radar topics"
                    raise SequenceError(f"{path}: {why}; choose one with --topic (topic=). Topics in the bag: "
                                        f"{_topics_text(reader)}")
                topic = topics[0]
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                raise SequenceError(f"{path}: no topic {topic!r}; topics in the bag: {_topics_text(reader)}")
            types = sorted({c.msgtype for c in conns})
            if len(types) != 1 or msgtype_name(types[0]) not in RADAR_MSGTYPES:
                raise SequenceError(
                    f"{path}: topic {topic} carries {', '.join(types)}, not a radar sweep radar-odom reads; "
                    f"supported: {', '.join(RADAR_MSGTYPES)}")
            self.topic, self.msgtype = topic, types[0]
            heads, firsts = [], []
            try:
                for conn, log_ns, raw in reader.messages(connections=conns):
                    try:
                        msg = reader.deserialize(raw, conn.msgtype)
                        head_ns, first_us = _first_azimuth_us(msg, conn.msgtype, self.geometry)
                    except Exception:  # one garbled message: timed by its log time, skipped when decoded
                        head_ns, first_us = int(log_ns), int(log_ns) // 1000
                    heads.append(head_ns)
                    firsts.append(first_us)
            except Exception as exc:
                raise SequenceError(f"{path}: the bag ends or breaks after {len(heads)} messages of {topic} "
                                    f"({type(exc).__name__}: {exc}); {_REPAIR}") from None
        finally:
            reader.close()
        if not heads:
            raise SequenceError(f"{path}: topic {topic} holds no messages")
        self.bag_path = path
        self.stamps_ns = np.asarray(heads, dtype=np.int64)
        names = [f"{path}[{topic} #{i}]" for i in range(len(heads))]
        base = fit_bag_time_base(path, firsts, self.geometry.sweep_period_s) if repair_stamps else None
        if base is None:
            super().__init__(path, BAG_FORMAT, names, firsts, None, {})
        else:
            super().__init__(path, BAG_FORMAT, names, base.times_us, None, {}, base.corrections_us, base)
        self._lock = threading.Lock()
        self._reader = None
        self._cursor = None
        self._next = 0

    def scan(self, index: int):
        """Decode message ``index`` of the topic into a `RadarScan` (`ScanFormatError` if it cannot be)."""
        with self._lock:
            if self._cursor is None or index < self._next:
                self.close()
                self._reader = _open_reader(self.bag_path)
                conns = [c for c in self._reader.connections if c.topic == self.topic]
                self._cursor = self._reader.messages(connections=conns)
                self._next = 0
            try:
                while True:
                    conn, _log_ns, raw = next(self._cursor)
                    self._next += 1
                    if self._next - 1 == index:
                        break
            except StopIteration:
                raise SequenceError(f"{self.bag_path}: message {index} of {self.topic} is gone; was the bag "
                                    "changed while it was read?") from None
            except Exception as exc:
                raise ScanFormatError(f"{self.paths[index]}: cannot read it ({type(exc).__name__}: {exc})") from None
            try:
                msg = self._reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise ScanFormatError(f"{self.paths[index]}: cannot deserialize the {conn.msgtype} message "
                                      f"({type(exc).__name__}: {exc})") from None
        scan = scan_from_msg(msg, conn.msgtype, self.geometry, source=self.paths[index])
        late = int(self.stamp_corrections_us[index])  # the sweep's times on the recording's time base
        return replace(scan, timestamps_us=scan.timestamps_us - late) if late else scan

    def close(self) -> None:
        """Close the reader `scan` keeps open (it reopens on the next call)."""
        if self._cursor is not None:
            self._cursor.close()
        if self._reader is not None:
            self._reader.close()
        self._reader = self._cursor = None
        self._next = 0

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


def open_bag(path, topic: str | None = None, repair_stamps: bool = True, **geometry) -> BagSequence:
    """A radar topic of a bag as a `BagSequence`. ``geometry``: `PolarImageGeometry` fields
    (``range_resolution_m``, ``range_offset_m``, ``sweep_period_s``, ``stamp``,
    ``azimuth_offset_rad``, ``encoder_size``). ``topic`` None: the bag's only radar topic.

    Raises `ConfigError` for an option that is not one of those fields (a typo), before the bag is opened."""
    import dataclasses

    from ..errors import ConfigError

    known = [f.name for f in dataclasses.fields(PolarImageGeometry) if f.init]
    unknown = sorted(set(geometry) - set(known))
    if unknown:
        raise ConfigError(f"unknown bag option{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                          f"open_bag takes {', '.join(known)}")
    return BagSequence(path, topic, PolarImageGeometry(**geometry), repair_stamps=repair_stamps)


def read_bag(path, topic: str | None = None, **geometry):
    """Yield the `RadarScan`s of a bag's radar topic in order (see `open_bag` for the arguments).

    Raises `MissingExtraError` without rosbags, `SequenceError` for a missing topic (the message
    lists the bag's topics), an unsupported message type or a truncated bag, `ScanFormatError`
    for a message that cannot be decoded.
    """
    seq = open_bag(path, topic, **geometry)
    try:
        for i in range(len(seq)):
            yield seq.scan(i)
    finally:
        seq.close()
