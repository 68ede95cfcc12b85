"""`benchmarks/scorecard.py`'s statistics: the spreads and the ship rule every release is judged by."""
import math

import numpy as np
import pytest

from fixtures import load_script


@pytest.fixture(scope="module")
def sc():
    return load_script("benchmarks/scorecard.py")


def test_mean_se_by_hand(sc):
    assert sc.mean_se([1.0, 3.0]) == pytest.approx((2.0, 1.0))  # sd √2, / √2
    assert sc.mean_se([5.0]) == (5.0, 0.0)
    assert sc.mean_se([2.0, float("nan"), None, 4.0]) == pytest.approx((3.0, 1.0))
    assert all(math.isnan(v) for v in sc.mean_se([]))


def test_ship_rule_needs_a_change_beyond_both_spreads(sc):
    # lower is better: worse only where the candidate exceeds the previous by more than hypot(spreads)
    assert sc.verdict((1.0, 0.3, True), (1.6, 0.4, True)) == "**worse**"
    assert sc.verdict((1.0, 0.3, True), (1.4, 0.4, True)) == "="  # 0.4 < 0.5
    assert sc.verdict((1.0, 0.3, True), (0.4, 0.4, True)) == "better"
    # higher is better (a share of plausible steps): the mirror
    assert sc.verdict((0.9, 0.01, False), (0.8, 0.01, False)) == "**worse**"
    assert sc.verdict((0.9, 0.01, False), (0.95, 0.01, False)) == "better"
    assert sc.verdict((math.nan, 0.1, True), (1.0, 0.1, True)) == "n/a"


def test_block_bootstrap_spread_grows_with_the_blocks_disagreement(sc):
    rng = np.random.default_rng(0)
    starts = np.arange(0, 200, 4, dtype=float)
    flat = np.column_stack([np.full_like(starts, 50.0), np.full_like(starts, 0.03), np.zeros_like(starts), starts])
    assert sc.block_bootstrap(flat, 1, rng) == pytest.approx(0.0, abs=1e-12)
    # blocks of 20 sweeps alternating 0.02 / 0.04: ten blocks, block means ±0.01 → se ≈ 0.01 / √10
    split = flat.copy()
    split[:, 1] = np.where((starts // sc.BLOCK_SWEEPS) % 2 == 0, 0.02, 0.04)
    se = sc.block_bootstrap(split, 1, np.random.default_rng(1), reps=2000)
    assert se == pytest.approx(0.01 / math.sqrt(10), rel=0.15)


def test_fresh_seeds_avoid_every_reserved_range(sc):
    import random

    seeds = sc.draw_seeds(50, random.Random(3))
    # training, validation, evaluation, demo and the other benchmarks' fixed seeds all lie below 100000
    assert len(set(seeds)) == 50 and min(seeds) >= 100_000
    assert seeds != sc.draw_seeds(50, random.Random(4))


def test_options_parse_as_a_user_writes_them(sc):
    assert sc.parse_options(["deskew=1", "motion_prior=off", "max_gap_s=2.5"]) == {
        "deskew": True, "motion_prior": False, "max_gap_s": 2.5}
    with pytest.raises(SystemExit, match="NAME=VALUE"):
        sc.parse_options(["deskew"])
