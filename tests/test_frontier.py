"""`benchmarks/frontier.py`'s pure parts: the candidate list, the Pareto set, the pick for a ship check,
the ratios and the table (nothing is timed or run here)."""

import numpy as np
import pytest

from fixtures import load_script


@pytest.fixture(scope="module")
def fr():
    return load_script("benchmarks/frontier.py")


def test_candidates_are_buildable_or_said_not_built(fr):
    assert fr.CANDIDATES["today"]["build"] == "shipped"
    for name, spec in fr.CANDIDATES.items():
        if name == "today":
            continue
        assert spec["settings"] is None or fr.parse_setting(spec["settings"])["coarse_factor"] == 4
        assert spec["quantize"] in (None, "", "first,last")
        assert spec["settings"] or spec["quantize"] is not None, name  # each differs from today's file
    assert {"half-resolution masker, trained", "coarse-to-fine translation"} <= set(fr.NOT_BUILT)
    assert fr.CANDIDATES["mask-md4"]["mask_downsample"] == 4  # the untrained next halving is built


def test_parse_setting(fr):
    assert fr.parse_setting("c4s6b2") == {"coarse_factor": 4, "coarse_stride": 6, "band_half_width": 2,
                                          "rotation": "polar"}
    with pytest.raises(SystemExit):
        fr.parse_setting("x4s6")


def test_half_paper_line(fr):
    assert fr.paper_half_ratio(15.5) == pytest.approx(0.5 * 16.9 / 15.5)
    assert fr.paper_half_ratio(8.45) == pytest.approx(1.0)


def test_pareto_keeps_the_undominated_fastest_first(fr):
    pts = {"today": (1.0, 10.0), "a": (0.8, 10.5), "b": (0.9, 11.0), "c": (0.7, 12.0), "d": (0.8, 10.5)}
    assert fr.pareto(pts) == ["c", "a", "d", "today"]  # b is beaten by a; a and d tie, both kept
    assert fr.pareto({"x": (1.0, 1.0)}) == ["x"]


def test_ship_candidate_is_the_fastest_with_no_row_worse(fr):
    rows = {"today": {"ratio": 1.0, "worse": 0}, "a": {"ratio": 0.7, "worse": 2}, "b": {"ratio": 0.85, "worse": 0},
            "c": {"ratio": 0.9, "worse": 0}, "slow": {"ratio": 1.1, "worse": 0}}
    assert fr.ship_candidate(rows) == "b"
    assert fr.ship_candidate({"today": {"ratio": 1.0, "worse": 0}, "s": {"ratio": 1.2, "worse": 0}}) is None


def test_ratio_stats(fr):
    ref = np.full(50, 0.010)
    faster = np.full(50, 0.008)
    s = fr.ratio_stats(ref, faster, np.random.default_rng(0), reps=20)
    assert s["ratio"] == pytest.approx(0.8) and s["p10_ratio"] == pytest.approx(0.8)
    assert s["ratio_spread"] == pytest.approx(0.0, abs=1e-12) and s["median_ms"] == pytest.approx(8.0)


def test_table_has_a_row_per_candidate(fr):
    row = {fr.KITTI_ROW: [2.0, 0.1, True], "real drive whole: translation %": [4.0, 0.5, True]}
    res = {"candidates": ["today", "int8-ff"],
           "timing": {n: {"ratio": r, "ratio_spread": 0.01, "p10_ratio": r} for n, r in (("today", 1.0),
                                                                                       ("int8-ff", 0.9))},
           "rows": {"today": row, "int8-ff": row},
           "verdicts": {"today": {"rows": 2, "worse": []}, "int8-ff": {"rows": 2, "worse": ["x"]}}}
    text = fr.table(res)
    lines = text.splitlines()
    assert len(lines) == 4 and "sim all t %" in lines[0] and "real whole t %" in lines[0]
    assert lines[3].startswith("| int8-ff | 0.900 ± 0.01 | 0.900 | 2 ± 0.1 | 4 ± 0.5 | 1 / 2 |")
