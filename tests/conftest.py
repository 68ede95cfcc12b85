"""Shared fixtures: where the real sweeps are.

The real Navtech sweeps (Oxford Radar RobotCar, RADIATE) are under non-commercial licences, so
they are never copied into the repository: tests read them from ``../shared/data/real/``
beside the checkout (CI has that path), or from ``$RADAR_ODOM_REAL_DATA``. Tests that need them
are marked ``real`` and are skipped, with the path in the reason, where the folder is absent.
"""
import os
from pathlib import Path

import pytest

REAL_DATA_ENV = "RADAR_ODOM_REAL_DATA"
DEFAULT_REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def real_data_path() -> Path:
    """The real-sweep folder: ``$RADAR_ODOM_REAL_DATA`` if set, else ``<checkout>/../shared/data/real``."""
    env = os.environ.get(REAL_DATA_ENV)
    return Path(env).expanduser() if env else DEFAULT_REAL_DATA


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """Path of the real sweeps; skips the test (saying where it looked) when the folder is absent."""
    path = real_data_path()
    if not path.is_dir():
        pytest.skip(
            f"real sweeps not found at {path} (set {REAL_DATA_ENV}, or place them at "
            "../shared/data/real beside the checkout)"
        )
    return path
