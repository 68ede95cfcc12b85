"""Every parameter of the simulator, as frozen dataclasses.

Two halves, chosen independently:

* `SimConfig` — the radar itself (`SensorConfig`: geometry, beam, power law, noise) and its
  artefacts (`ArtefactConfig`: saturation streaks, multipath ghosts, phase-noise rings, range
  sidelobes, near-range clutter) plus the label rule. Defaults are a Navtech CTS350-X as in the
  Oxford Radar RobotCar dataset: 400 azimuths × 3768 bins at 0.0432 m, 4 Hz, encoder 5600 counts
  stepping 14.
* `Scenario` — what is driven through: the ego drive (`DriveConfig`), the static world
  (`WorldConfig`) and the moving traffic (`TrafficConfig`). Named presets live in
  `radar_odom.sim.scenarios.SCENARIOS`.

Power is handled in dB relative to the receiver noise floor (0 dB = mean noise power at
``noise_floor_db``); a reflector of ``reflectivity_db`` R at range r returns
``R - 10·range_exponent·log10(r / 1 m)`` dB before attenuation by what lies in front of it.
The 8-bit output maps ``floor_db`` to 0 and adds one count per ``db_per_count`` dB, the way a
Navtech head reports log power.

Ranges are ``(low, high)`` tuples drawn uniformly per object.

The sensor geometry and timing are the CTS350-X's own. The power model (count mapping, integer
power quantisation, noise floor, near-range clutter, point spread, speckle correlation and
azimuth gain wander) is calibrated against real Oxford Radar RobotCar sweeps with
`radar_odom.sim.realism` (``benchmarks/realism.py``): every statistic there lies within ±30 % of
the real sweeps' (``tests/test_realism.py``). Artefact levels and the world remain tuned by eye.
`SENSOR_PRESETS` holds the Oxford and RADIATE installations; `randomised_config` draws the
training-time variations around them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from ..errors import RadarOdomError

Range = tuple[float, float]


class SimConfigError(RadarOdomError, ValueError):
    """A simulator argument is unusable (unknown scenario, negative seed, zero frames, ...)."""


@dataclass(frozen=True)
class SensorConfig:
    """Radar geometry, beam and power model (defaults: Navtech CTS350-X, Oxford)."""

    num_azimuths: int = 400
    num_bins: int = 3768
    range_resolution_m: float = 0.0432
    sweep_hz: float = 4.0
    encoder_size: int = 5600
    encoder_step: int = 14
    min_range_m: float = 0.5  # rays start here: nothing inside the sensor housing
    beamwidth_deg: float = 2.4  # azimuth beam, full width at half maximum
    range_lobe_sigma_bins: float = 3.0  # main range lobe (chirp bandwidth), Gaussian sigma
    range_exponent: float = 1.5  # power ∝ 1/r^k (k=2: beam-filling surfaces; 4: point targets)
    incidence_exponent: float = 1.5  # surface return ∝ cos(incidence)^n
    min_incidence_cos: float = 0.06  # floor on cos(incidence) so grazing walls still return a little
    max_range_extent_m: float = 12.0  # a grazing wall fills at most this much range in one beam
    extent_beam_fraction: float = 0.6  # range profile sigma of a grazing return, in beam sigmas
    # (below 1: the azimuth blur applied afterwards widens it again)
    extent_power_exponent: float = 0.5  # per-bin power of an extended return ∝ 1/n_bins^e
    noise: bool = True  # receiver noise and speckle; False gives a deterministic, noise-free sweep
    speckle_cell_bins: int = 3  # speckle is constant over this many range bins (resolution cell)
    scintillation_db: float = 2.5  # per-sweep random gain of each surface piece / scatterer
    # (aspect-dependent radar cross-section: the same wall is not equally bright twice)
    noise_floor_db: float = 0.0  # mean receiver noise power at near range
    noise_floor_slope_db_per_100m: float = 1.0  # real Oxford floors rise a little with range
    ground_clutter_db: float = 2.0  # road-surface/ground returns: raise the floor near the
    ground_clutter_decay_m: float = 15.0  # sensor by this much, fading (in dB) over this range
    floor_db: float = -4.5  # dB mapped to count 0 (mean noise sits near count 6–10, as on Oxford)
    db_per_count: float = 0.5  # dB per 8-bit count (Navtech: 0.5 dB)
    # A Navtech head quantises *linear* power to integers n before taking the log: real Oxford
    # sweeps hold only the counts round(10·log10(n) / db_per_count) (0, 6, 10, 12, 14, …), 0 for
    # n ≤ 1. True: power in units of 10^(floor_db/10) is floored to an integer first.
    integer_power: bool = True
    # Per-sweep, per-azimuth gain (dB, Gaussian, smoothed over this many rows): real heads show
    # strong azimuth-to-azimuth power changes (std/mean of the row means ≈ 0.4–0.5 on Oxford).
    azimuth_gain_db: float = 3.0
    azimuth_gain_rows: float = 2.0
    # Speckle as a complex-Gaussian field smoothed by the point-spread function (sigma in rows
    # and bins), so it is correlated over a resolution cell along both axes; 0 keeps the
    # older model (one exponential draw per ``speckle_cell_bins`` bins, independent rows).
    speckle_sigma_rows: float = 1.3
    speckle_sigma_bins: float = 3.5
    drop_azimuth_probability: float = 0.0  # chance that a row is dropped (written invalid)

    @property
    def max_range_m(self) -> float:
        return self.num_bins * self.range_resolution_m

    @property
    def period_us(self) -> int:
        return int(round(1e6 / self.sweep_hz))


@dataclass(frozen=True)
class ArtefactConfig:
    """What makes real radar hard besides noise. Levels are dB relative to the causing return."""

    enabled: bool = True
    streak_threshold_db: float = 56.0  # a row whose strongest return exceeds this is raised...
    streak_db_per_db: float = 1.0  # ...by this many dB of noise per dB of excess...
    streak_max_db: float = 12.0  # ...at most (receiver saturation)
    ghost_threshold_db: float = 42.0  # returns stronger than this leave multipath ghosts...
    ghosts: tuple[tuple[float, float], ...] = ((2.0, -24.0), (3.0, -34.0))
    # ...at these multiples of the reflector's range, this many dB below it (bounces between
    # the ego vehicle and the reflector)
    ring_threshold_db: float = 54.0  # returns stronger than this draw a phase-noise arc
    ring_relative_db: float = -28.0  # arc level next to the return
    ring_half_width_rows: int = 30  # arc spans this many azimuth rows either side
    ring_decay_rows: float = 12.0  # e-folding of the arc level along azimuth
    sidelobe_threshold_db: float = 44.0  # returns stronger than this show range sidelobes
    sidelobe_relative_db: float = -32.0
    sidelobe_half_width_bins: int = 40
    sidelobe_decay_bins: float = 10.0
    fixed_rings: int = 4  # rings at fixed ranges (radome / internal reflections): a per-drive
    fixed_ring_range_m: Range = (4.0, 100.0)  # pattern static in the sensor frame, raising the
    fixed_ring_db: Range = (2.0, 6.0)  # noise floor by this much over a few bins
    fixed_ring_width_bins: float = 3.0
    near_clutter_range_m: float = 2.5  # the vehicle's own returns, static in the sensor frame
    near_clutter_db: float = -7.0  # level at zero range (before the beam and range-lobe gain)
    near_clutter_spread_db: float = 3.0  # fixed per-azimuth variation (roof rack, mount)


@dataclass(frozen=True)
class LabelConfig:
    """A polar cell is labelled static (255) when its expected static power exceeds the expected
    power of everything else (moving objects, ghosts, rings, streaks, near clutter) and the
    noise floor by ``static_margin_db``."""

    static_margin_db: float = 3.0


@dataclass(frozen=True)
class SimConfig:
    """The radar model: sensor, artefacts, labels and the time base of the written drive."""

    sensor: SensorConfig = field(default_factory=SensorConfig)
    artefacts: ArtefactConfig = field(default_factory=ArtefactConfig)
    labels: LabelConfig = field(default_factory=LabelConfig)
    base_timestamp_us: int = 1547131046000000  # Oxford-era epoch of seed 0's first sweep
    seed_offset_us: int = 3_600_000_000  # each seed starts an hour later, so drives never overlap

    def with_sensor(self, **kw) -> SimConfig:
        """A copy with some `SensorConfig` fields replaced (e.g. ``num_bins=800`` for tests)."""
        return replace(self, sensor=replace(self.sensor, **kw))

    def with_artefacts(self, **kw) -> SimConfig:
        return replace(self, artefacts=replace(self.artefacts, **kw))


@dataclass(frozen=True)
class DriveConfig:
    """The ego drive: a road centreline of straights, bends and intersection turns, the ego's
    lane (with lane changes) and a speed profile with acceleration limits and stops."""

    max_speed_mps: float = 12.0  # hard cap on the ego speed (the brief allows 0-15 m/s)
    cruise_speed_mps: Range = (7.0, 12.0)  # target speed, redrawn per straight
    max_yaw_rate_dps: float = 30.0
    max_accel_mps2: float = 1.5
    max_decel_mps2: float = 2.5
    max_lateral_accel_mps2: float = 2.5
    straight_length_m: Range = (60.0, 180.0)  # between intersections / bends
    turn_probability: float = 0.35  # an intersection where the ego turns 90° left or right
    bend_probability: float = 0.25  # a gentle bend with no intersection
    junction_probability: float = 0.3  # a straight-through intersection (crossing traffic)
    turn_radius_m: Range = (9.0, 16.0)
    # how far an intersection turn turns; (90, 90) draws nothing (the drives of every scenario before "junctions")
    turn_angle_deg: Range = (90.0, 90.0)
    bend_angle_deg: Range = (10.0, 45.0)
    bend_radius_m: Range = (60.0, 200.0)
    curvature_ramp_m: float = 8.0  # curvature changes linearly over this length (smooth yaw rate)
    stop_probability: float = 0.3  # chance the ego stops before an intersection
    stop_duration_s: Range = (2.0, 8.0)
    lane_width_m: float = 3.5
    lanes_per_direction: int = 1
    lane_changes_per_km: float = 0.0  # needs lanes_per_direction >= 2
    lane_change_length_m: Range = (35.0, 60.0)
    lead_in_m: float = 250.0  # straight road behind the start (followers behind, world behind)
    constant_speed_mps: float | None = None  # test hook: straight road, this exact speed, no stops
    # test hook with constant_speed_mps: after the lead-in the road bends at this constant curvature
    # (1/m, positive turns right) instead of running straight: a steady yaw rate (benchmarks/yaw_precision.py)
    constant_curvature_per_m: float = 0.0


@dataclass(frozen=True)
class WorldConfig:
    """The static world along the route, as zones of urban blocks, corridors and open fields.

    Materials: reflectivity in dB (see module docstring) and transmission, the power fraction
    that passes through (walls occlude, fences and trees let some through).
    """

    zone_weights: tuple[float, float, float] = (0.8, 0.1, 0.1)  # urban, corridor, open
    zone_length_m: Range = (120.0, 400.0)
    sidewalk_width_m: float = 3.0
    parking_width_m: float = 2.2
    # buildings (urban zones)
    building_setback_m: Range = (1.0, 6.0)  # beyond the sidewalk
    building_length_m: Range = (12.0, 45.0)
    building_gap_m: Range = (0.0, 8.0)
    building_depth_m: Range = (10.0, 30.0)
    building_step_probability: float = 0.4  # facade recessed/protruding part (corners to match on)
    building_reflectivity_db: Range = (56.0, 68.0)
    building_transmission: float = 0.01
    # fences / railings / hedges
    fence_probability: float = 0.35  # per building gap / open stretch side
    fence_reflectivity_db: Range = (44.0, 52.0)
    fence_transmission: float = 0.6
    # corridor zones: continuous walls both sides (constrain y, not x)
    corridor_setback_m: Range = (0.5, 3.0)
    corridor_wall_reflectivity_db: Range = (58.0, 66.0)
    # street furniture
    parked_cars_per_100m: float = 4.0  # per side, urban zones
    car_reflectivity_db: Range = (60.0, 70.0)
    car_transmission: float = 0.03
    pole_spacing_m: Range = (18.0, 40.0)
    pole_reflectivity_db: Range = (50.0, 60.0)
    trees_per_100m: float = 2.5  # per side
    tree_radius_m: Range = (0.7, 2.2)
    tree_reflectivity_db: Range = (40.0, 48.0)
    tree_transmission: float = 0.45
    # diffuse clutter (kerbs, bushes, grass, signs): weak point scatterers
    clutter_per_100m2: float = 8.0
    clutter_band_m: float = 100.0  # clutter lies within this distance of the road edge
    clutter_reflectivity_db: Range = (34.0, 52.0)
    clutter_front_fraction: float = 0.6  # share of clutter between kerb and facades
    facade_detail_spacing_m: float = 2.5  # mean spacing of point returns along facades
    open_clutter_scale: float = 0.35  # clutter density factor in open zones
    open_feature_spacing_m: Range = (60.0, 200.0)  # isolated posts/trees in open zones
    # highway furniture
    median_barrier: bool = False  # guard rail on the centreline (highways)
    guardrail: bool = False  # guard rails at both road edges instead of kerbs
    guardrail_reflectivity_db: Range = (46.0, 52.0)
    guardrail_transmission: float = 0.5
    guardrail_post_spacing_m: Range = (1.5, 4.5)
    noise_barrier_probability: float = 0.0  # per zone side on highways: tall occluding wall
    # test hooks, in the frame of the ego at the first azimuth of sweep 0 (x forward, y right)
    procedural: bool = True  # False: only the extra reflectors below
    extra_points: tuple[tuple[float, float, float], ...] = ()  # (x_m, y_m, reflectivity_db)
    extra_walls: tuple[tuple[float, float, float, float, float, float], ...] = ()
    # (x0_m, y0_m, x1_m, y1_m, reflectivity_db, transmission)


@dataclass(frozen=True)
class TrafficConfig:
    """Moving objects. Vehicles are boxes; pedestrians point scatterers; cyclists small boxes."""

    oncoming_per_km: float = 20.0
    same_direction_per_km: float = 0.0  # in lanes the ego never uses (multi-lane roads)
    crossing_per_intersection: Range = (0.0, 3.0)
    followers_ahead: int = 2  # vehicles on the ego's own path at the ego's speed
    followers_behind: int = 1
    follower_gap_m: Range = (9.0, 30.0)
    vehicle_speed_mps: Range = (6.0, 13.0)
    vehicle_length_m: Range = (4.2, 4.9)
    vehicle_width_m: Range = (1.7, 1.9)
    large_vehicle_probability: float = 0.1  # vans, buses, lorries
    large_vehicle_length_m: Range = (6.5, 12.0)
    large_vehicle_width_m: Range = (2.2, 2.5)
    vehicle_reflectivity_db: Range = (68.0, 78.0)  # metal and corner reflectors: brighter than walls
    vehicle_transmission: float = 0.02
    pedestrians_per_100m: float = 1.5
    pedestrian_speed_mps: Range = (0.8, 1.7)
    pedestrian_reflectivity_db: Range = (34.0, 42.0)
    cyclists_per_km: float = 4.0
    cyclist_speed_mps: Range = (3.5, 7.0)
    cyclist_reflectivity_db: Range = (44.0, 52.0)


@dataclass(frozen=True)
class Scenario:
    """What is driven through: drive, world and traffic."""

    name: str = "urban"
    drive: DriveConfig = field(default_factory=DriveConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)

    def with_world(self, **kw) -> Scenario:
        return replace(self, world=replace(self.world, **kw))

    def with_drive(self, **kw) -> Scenario:
        return replace(self, drive=replace(self.drive, **kw))

    def with_traffic(self, **kw) -> Scenario:
        return replace(self, traffic=replace(self.traffic, **kw))
