"""Named scenario presets: urban (default), heavy_traffic, open, highway, junctions.

Each is a `Scenario` (drive + world + traffic); the radar model (`SimConfig`) is chosen
separately. Use `get_scenario` to resolve a name with a helpful error.
"""
from __future__ import annotations

from .config import DriveConfig, Scenario, SimConfigError, TrafficConfig, WorldConfig

URBAN = Scenario(name="urban")

HEAVY_TRAFFIC = Scenario(
    name="heavy_traffic",
    drive=DriveConfig(
        cruise_speed_mps=(4.0, 9.0), max_speed_mps=10.0, stop_probability=0.6,
        stop_duration_s=(3.0, 12.0), lanes_per_direction=2, lane_changes_per_km=2.0,
        junction_probability=0.4,
    ),
    world=WorldConfig(parked_cars_per_100m=6.0),
    traffic=TrafficConfig(
        oncoming_per_km=45.0, crossing_per_intersection=(1.0, 5.0), followers_ahead=2,
        followers_behind=2, follower_gap_m=(6.0, 18.0), large_vehicle_probability=0.2,
        pedestrians_per_100m=4.0, cyclists_per_km=10.0,
    ),
)

# the paper's pathological cases: long corridors that constrain y but not x, and open fields
OPEN = Scenario(
    name="open",
    drive=DriveConfig(
        cruise_speed_mps=(9.0, 13.0), max_speed_mps=13.0, straight_length_m=(200.0, 500.0),
        turn_probability=0.0, bend_probability=0.15, junction_probability=0.1,
        bend_radius_m=(150.0, 400.0), stop_probability=0.0,
    ),
    world=WorldConfig(
        zone_weights=(0.0, 0.5, 0.5), zone_length_m=(200.0, 600.0), trees_per_100m=0.5,
        clutter_per_100m2=1.5, fence_probability=0.5,
    ),
    traffic=TrafficConfig(
        oncoming_per_km=5.0, followers_ahead=1, followers_behind=0, pedestrians_per_100m=0.1,
        cyclists_per_km=1.0, crossing_per_intersection=(0.0, 1.0),
    ),
)

HIGHWAY = Scenario(
    name="highway",
    drive=DriveConfig(
        max_speed_mps=15.0, cruise_speed_mps=(12.0, 15.0), straight_length_m=(200.0, 600.0),
        turn_probability=0.0, bend_probability=0.35, junction_probability=0.0,
        bend_angle_deg=(5.0, 25.0), bend_radius_m=(300.0, 900.0), stop_probability=0.0,
        lane_width_m=3.6, lanes_per_direction=3, lane_changes_per_km=1.0,
    ),
    world=WorldConfig(
        zone_weights=(0.0, 0.3, 0.7), parking_width_m=2.8, sidewalk_width_m=2.0,
        trees_per_100m=1.5, pole_spacing_m=(15.0, 45.0), clutter_per_100m2=3.0,
        guardrail=True, median_barrier=True, noise_barrier_probability=0.25,
    ),
    traffic=TrafficConfig(
        oncoming_per_km=30.0, same_direction_per_km=20.0, vehicle_speed_mps=(11.0, 17.0),
        followers_ahead=1, followers_behind=1, follower_gap_m=(15.0, 40.0),
        large_vehicle_probability=0.25, pedestrians_per_100m=0.0, cyclists_per_km=0.0,
        crossing_per_intersection=(0.0, 0.0),
    ),
)

# sharp junction turns (issue 50): the urban world, but intersections every 10-35 m where the ego mostly turns
# 30-90 deg on a tight radius, slowed to 3.4-7 m/s by the lateral-acceleration limit (cruising 5-10 m/s between):
# 1-4 turns of >= 30 deg within 2 s in every 100-sweep drive of seeds 0-15 (benchmarks/junction_turns.py)
JUNCTIONS = Scenario(
    name="junctions",
    drive=DriveConfig(
        cruise_speed_mps=(5.0, 10.0), max_speed_mps=10.0, straight_length_m=(10.0, 35.0),
        turn_probability=0.8, bend_probability=0.1, junction_probability=0.1,
        turn_angle_deg=(30.0, 90.0), turn_radius_m=(8.0, 14.0),
        stop_probability=0.05, stop_duration_s=(1.0, 3.0),
    ),
)

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (URBAN, HEAVY_TRAFFIC, OPEN, HIGHWAY, JUNCTIONS)}


def get_scenario(scenario: str | Scenario) -> Scenario:
    """The preset called ``scenario`` (or ``scenario`` itself if it is a `Scenario`)."""
    if isinstance(scenario, Scenario):
        return scenario
    try:
        return SCENARIOS[scenario]
    except (KeyError, TypeError):
        raise SimConfigError(
            f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}"
        ) from None


def steady_scenario(scenario: str | Scenario = "urban", speed_mps: float = 10.0, yaw_deg_per_sweep: float = 0.0,
                    **drive_overrides) -> Scenario:
    """``scenario``'s world driven at exactly ``speed_mps`` on a straight road that, after its lead-in,
    bends by ``yaw_deg_per_sweep`` each sweep (positive: turning right, +yaw; 0: straight), through the
    drive's test hooks (`DriveConfig.constant_speed_mps`, ``constant_curvature_per_m``) — the steady
    drives the benchmarks measure yaw precision, de-skew and gaps on. ``drive_overrides``: more
    `DriveConfig` fields (e.g. ``curvature_ramp_m``)."""
    import math
    from dataclasses import replace

    from .config import SimConfig

    base = get_scenario(scenario)
    period_s = SimConfig().sensor.period_us * 1e-6
    curvature = math.radians(float(yaw_deg_per_sweep)) / (float(speed_mps) * period_s)
    drive = replace(base.drive, constant_speed_mps=float(speed_mps), constant_curvature_per_m=curvature,
                    **drive_overrides)
    return replace(base, drive=drive)

