"""Sensor presets of real installations, and the training-time randomisation around them.

* ``"oxford"``: the Navtech CTS350-X of Oxford Radar RobotCar (400 azimuths × 3768 bins at
  0.0432 m; integer linear power, 0.5 dB per count) — the `SimConfig` defaults, calibrated
  against the real Oxford sweeps (`radar_odom.sim.realism`, ``benchmarks/realism.py``).
* ``"radiate"``: the same sensor as recorded in RADIATE (576 bins at 0.1736 m, a brighter,
  un-quantised count mapping, a weaker azimuth gain wander), fitted the same way to the
  RADIATE fog sequence's statistics.

`randomised_config` draws a sensor around both for a training drive: count mapping (offset
and scale), power quantisation, noise floor and its range slope, point spread and speckle
correlation, azimuth gain wander, near-range clutter, range fall-off and the geometry of either
installation. A model trained across these draws cannot rely on one radar's absolute power.
"""
from __future__ import annotations

import numpy as np

from .config import SimConfig, SimConfigError

SENSOR_PRESETS: dict[str, SimConfig] = {
    "oxford": SimConfig(),
    "radiate": SimConfig().with_sensor(
        num_bins=576, range_resolution_m=0.173611, integer_power=False, floor_db=-12.0,
        range_lobe_sigma_bins=1.0, speckle_sigma_bins=1.3, azimuth_gain_db=2.2,
    ),
}


def get_sensor_preset(name: str | SimConfig) -> SimConfig:
    """The preset called ``name`` (or ``name`` itself if it is a `SimConfig`)."""
    if isinstance(name, SimConfig):
        return name
    try:
        return SENSOR_PRESETS[name]
    except (KeyError, TypeError):
        raise SimConfigError(
            f"unknown sensor preset {name!r}; choose one of {', '.join(SENSOR_PRESETS)}"
        ) from None


def randomised_config(seed: int) -> SimConfig:
    """A sensor drawn for one training drive (deterministic in ``seed``).

    Ranges were chosen to cover both real installations we have sweeps of (Oxford: median
    power 0.03, integer-quantised; RADIATE: median 0.09, continuous) with margin either side.
    """
    rng = np.random.default_rng([int(seed), 0x5E45])
    radiate = rng.random() < 0.3
    base = SENSOR_PRESETS["radiate" if radiate else "oxford"].sensor
    bin_m = base.range_resolution_m
    psf_m = rng.uniform(0.07, 0.22)  # range point spread sigma, metres
    return SimConfig().with_sensor(
        num_bins=base.num_bins,
        range_resolution_m=bin_m,
        integer_power=bool(rng.random() < 0.6),
        floor_db=float(rng.uniform(-14.0, -2.0)),
        db_per_count=float(rng.uniform(0.35, 0.7)),
        noise_floor_db=float(rng.normal(0.0, 1.5)),
        noise_floor_slope_db_per_100m=float(rng.uniform(-3.0, 2.0)),
        ground_clutter_db=float(rng.uniform(0.0, 8.0)),
        range_exponent=float(rng.uniform(1.4, 2.1)),
        range_lobe_sigma_bins=float(max(0.5, psf_m / bin_m)),
        speckle_sigma_bins=float(max(0.6, rng.uniform(0.8, 1.4) * psf_m / bin_m)),
        speckle_sigma_rows=float(rng.uniform(0.8, 1.8)),
        beamwidth_deg=float(rng.uniform(1.8, 3.0)),
        azimuth_gain_db=float(rng.uniform(0.5, 4.5)),
        azimuth_gain_rows=float(rng.uniform(1.0, 4.0)),
        scintillation_db=float(rng.uniform(1.5, 4.0)),
    ).with_artefacts(
        near_clutter_db=float(rng.uniform(-12.0, 8.0)),
        near_clutter_range_m=float(rng.uniform(1.5, 4.0)),
        fixed_rings=int(rng.integers(0, 6)),
        streak_threshold_db=float(rng.uniform(50.0, 62.0)),
    )
