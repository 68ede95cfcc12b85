"""`benchmarks/azimuth_slips.py`'s row matcher, the measurement behind the README's finding that
RADIATE sweeps slip by whole azimuth bins within a sweep: it must find no shift between a sweep
and itself, a constant shift for a rotation, and the row where a slip starts."""

import numpy as np

from fixtures import load_script


def _row_shifts():
    return load_script("benchmarks/azimuth_slips.py").row_shifts


def _sweep(seed=0, rows=400, bins=300):
    """A polar sweep with azimuth structure (targets a few rows wide) over speckle."""
    rng = np.random.default_rng(seed)
    power = 0.05 * rng.random((rows, bins))
    for _ in range(120):
        a, r = rng.integers(rows), rng.integers(bins - 10)
        power[(a + np.arange(-2, 3)) % rows, r : r + rng.integers(2, 10)] += rng.uniform(0.2, 0.9)
    return np.clip(power, 0.0, 1.0)


def test_row_shifts_zero_constant_and_a_slip_from_its_row_on():
    row_shifts = _row_shifts()
    prev = _sweep()
    assert np.all(row_shifts(prev, prev) == 0)
    # the whole scene turned by two bins: row a of the new sweep shows what row a + 2 showed
    turned = np.roll(prev, -2, axis=0)
    assert np.mean(row_shifts(prev, turned) == 2) > 0.95
    # a slip: from row 150 on each row shows the azimuth one bin further on (one azimuth dropped there)
    slipped = prev.copy()
    slipped[150:] = np.roll(prev, -1, axis=0)[150:]
    s = row_shifts(prev, slipped)
    assert np.mean(s[:140] == 0) > 0.95 and np.mean(s[160:] == 1) > 0.95
