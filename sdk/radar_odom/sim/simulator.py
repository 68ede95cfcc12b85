"""The simulator: one drive (seed × scenario × radar model), rendered sweep by sweep.

Time base: sweep k's azimuth row a is stamped ``base + k·period + round(a·period/A)`` µs with
``base = config.base_timestamp_us + (seed mod 10^6)·config.seed_offset_us``; drive time
t = 0 s is the first azimuth of sweep 0, where the ego is at the world origin heading +x.
A sweep's pose is the ego pose at its mid time (mean of its azimuth timestamps), like
Oxford's ``source_timestamp``; relative poses follow the Oxford convention (`radar_odom.se2`).

Every random choice comes from a generator seeded by ``(seed, stream)``: the world, drive,
traffic and fixed sensor pattern once per drive, and one generator per sweep index, so sweeps
can be rendered in any order with identical results.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..scan import RadarScan
from ..se2 import invert, se2, to_xyyaw
from .config import Scenario, SimConfig, SimConfigError
from .drive import EgoDrive, plan_drive
from .scenarios import get_scenario
from .sensor import Points, Segments, SweepRenderer
from .traffic import Traffic, build_traffic
from .world import StaticWorld, build_world

_STREAM_DRIVE, _STREAM_WORLD, _STREAM_TRAFFIC, _STREAM_SENSOR, _STREAM_SWEEP = 1, 2, 3, 4, 5
CULL_MARGIN_M = 6.0  # the ego moves < 4 m within a sweep at 15 m/s


@dataclass(frozen=True)
class SimFrame:
    """One simulated sweep.

    Attributes:
        scan: the sweep (power uint8-quantised, float32 in [0, 1]; encoder counts set).
        static_label: uint8[A, B], 255 where the power comes mainly from the static world.
        pose_mid: float64[3, 3] absolute ego pose at the sweep's mid time (world frame).
        pose_rel: float64[3] Oxford (x, y, yaw) of this sweep in the previous one; None first.
    """

    scan: RadarScan
    static_label: np.ndarray
    pose_mid: np.ndarray
    pose_rel: np.ndarray | None


# 2**63 frames ran until the disk filled: 100 000 sweeps is a 7-hour drive at 4 Hz and ~57 GB of PNGs
MAX_FRAMES = 100_000
MAX_SEED = 2**63 - 1  # what an int64 holds; any seed is a world, larger ones are typing slips


class Simulator:
    """A drive of ``frames`` sweeps: world, traffic and ego trajectory built on construction.

    Attributes: ``drive`` (`EgoDrive`), ``world`` (`StaticWorld`), ``traffic`` (`Traffic`),
    ``renderer`` (`SweepRenderer`), ``scenario``, ``config``, ``base_us``.
    """

    def __init__(self, seed: int, frames: int, scenario: str | Scenario = "urban", config: SimConfig | None = None):
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or not 0 <= seed <= MAX_SEED:
            raise SimConfigError(f"seed must be an integer from 0 to {MAX_SEED} (2**63 - 1), got {seed!r}")
        if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or not 1 <= frames <= MAX_FRAMES:
            raise SimConfigError(f"frames must be an integer from 1 to {MAX_FRAMES} (a "
                                 f"{MAX_FRAMES / 4 / 3600:.0f}-hour drive at 4 Hz), got {frames!r}")
        if config is not None and not isinstance(config, SimConfig):
            raise SimConfigError(f"config must be a radar_odom.sim.SimConfig, got {type(config).__name__}")
        self.seed, self.frames = int(seed), int(frames)
        self.scenario = get_scenario(scenario)
        self.config = config or SimConfig()
        sc, s = self.scenario, self.config.sensor
        if s.num_azimuths < 8 or s.num_bins < 8 or s.encoder_step * s.num_azimuths > s.encoder_size:
            raise SimConfigError(
                f"sensor geometry {s.num_azimuths} azimuths × {s.num_bins} bins with encoder step "
                f"{s.encoder_step} of {s.encoder_size} is not a sweep; keep step·azimuths ≤ encoder size"
            )
        gen = lambda stream: np.random.default_rng([self.seed, stream])  # noqa: E731
        self.duration_s = self.frames / s.sweep_hz
        self.drive: EgoDrive = plan_drive(sc.drive, self.duration_s + 1.0, s.max_range_m + 60.0, gen(_STREAM_DRIVE))
        self.world: StaticWorld = build_world(sc.world, self.drive.road, gen(_STREAM_WORLD))
        edge = sc.drive.lanes_per_direction * sc.drive.lane_width_m + sc.world.parking_width_m
        self.traffic: Traffic = build_traffic(
            sc.traffic, sc.drive, self.drive, edge, sc.world.sidewalk_width_m, self.duration_s, gen(_STREAM_TRAFFIC)
        )
        self.renderer = SweepRenderer(self.config, gen(_STREAM_SENSOR))
        self.base_us = int(self.config.base_timestamp_us + (self.seed % 1_000_000) * self.config.seed_offset_us)

    # ---------------------------------------------------------------- time and poses
    def timestamps_us(self, k: int) -> np.ndarray:
        """int64[A] azimuth timestamps of sweep ``k``."""
        return self.base_us + k * self.config.sensor.period_us + self.renderer.row_offset_us

    def drive_time_s(self, timestamps_us) -> np.ndarray:
        return (np.asarray(timestamps_us, dtype=np.int64) - self.base_us) * 1e-6

    def pose_mid(self, k: int) -> np.ndarray:
        """float64[3, 3] ego pose at sweep ``k``'s mid time (mean azimuth time)."""
        t_mid = float(np.mean(self.drive_time_s(self.timestamps_us(k))))
        xy, yaw = self.drive.pose_at(t_mid)
        return se2(float(xy[0]), float(xy[1]), float(yaw))

    # ---------------------------------------------------------------- rendering
    def scene(self, k: int):
        """What sweep ``k`` sees: (ego positions float64[A, 2] and headings float64[A] at each azimuth's
        time, [static, moving] `Segments`, [static, moving] `Points`), in world metres."""
        t = self.drive_time_s(self.timestamps_us(k))
        orig, yaw = self.drive.pose_at(t)
        centre = orig[len(orig) // 2]
        radius = self.config.sensor.max_range_m + CULL_MARGIN_M
        seg_near, pts_near = self.world.near(centre, radius)
        w = self.world
        segments = [Segments(w.seg_a_m[seg_near], w.seg_b_m[seg_near], w.seg_refl_db[seg_near],
                             w.seg_trans_db[seg_near], moving=False)]
        a, b, refl, trans = self.traffic.box_segments(self.drive, t, centre, radius)
        segments.append(Segments(a, b, refl, trans, moving=True))
        points = [Points(w.pts_m[pts_near], w.pts_refl_db[pts_near], moving=False)]
        ped_xy, ped_refl = self.traffic.pedestrian_points(self.drive, t, centre, radius)
        points.append(Points(ped_xy, ped_refl, moving=True))
        return orig, yaw, segments, points

    def render(self, k: int):
        """(power uint8[A, B], label uint8[A, B], valid bool[A], timestamps int64[A]) of sweep k."""
        orig, yaw, segments, points = self.scene(k)
        rng = np.random.default_rng([self.seed, _STREAM_SWEEP, k])
        power, label, valid = self.renderer.render(orig, yaw, segments, points, rng)
        return power, label, valid, self.timestamps_us(k)

    def frame(self, k: int, previous_pose_mid: np.ndarray | None = None) -> SimFrame:
        """Sweep ``k`` as a `SimFrame` (``pose_rel`` relative to sweep k-1; None for k = 0)."""
        if not 0 <= k < self.frames:
            raise SimConfigError(f"sweep index {k} outside this drive's 0..{self.frames - 1}")
        power, label, valid, ts = self.render(k)
        r = self.renderer
        scan = RadarScan.from_arrays(
            ts, r.azimuths_rad.astype(np.float32), power, valid=valid,
            range_resolution_m=self.config.sensor.range_resolution_m, encoder_counts=r.encoder_counts,
            source=f"sim:{self.scenario.name}:seed{self.seed}:sweep{k}",
        )
        pose = self.pose_mid(k)
        rel = None
        if k > 0:
            prev = self.pose_mid(k - 1) if previous_pose_mid is None else previous_pose_mid
            rel = to_xyyaw(invert(prev) @ pose)
        return SimFrame(scan=scan, static_label=label, pose_mid=pose, pose_rel=rel)

    def __iter__(self) -> Iterator[SimFrame]:
        prev = None
        for k in range(self.frames):
            fr = self.frame(k, prev)
            prev = fr.pose_mid
            yield fr


def simulate_drive(seed: int, frames: int, scenario: str | Scenario = "urban",
                   config: SimConfig | None = None) -> Iterator[SimFrame]:
    """Stream ``frames`` simulated sweeps of one drive, in memory (nothing touches the disk).

    Args:
        seed: names the procedural world, drive and traffic (same seed ⇒ identical sweeps).
        frames: number of sweeps (4 Hz with the default sensor).
        scenario: a preset name from `SCENARIOS` (urban, heavy_traffic, open, highway) or a
            `Scenario`.
        config: the radar model (`SimConfig`); defaults to a Navtech CTS350-X.
    Yields:
        `SimFrame` per sweep, in time order.
    """
    return iter(Simulator(seed, frames, scenario, config))
