"""Real recordings as training pairs (`radar_odom_export.real_pairs`): skip-k pairs and their
composed poses, the search-window filter, the real/simulated mix, gain/floor randomisation,
the held-out stretch, and a training run that mixes them."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from test_train import TINY  # noqa: E402  (the small trainable grid of the training tests)

from radar_odom.profiles import get_profile  # noqa: E402
from radar_odom.se2 import chain_relative, invert, to_xyyaw  # noqa: E402
from radar_odom_export import data as D  # noqa: E402
from radar_odom_export.real_pairs import (  # noqa: E402
    GainFloor,
    MixedPairs,
    SkipPairs,
    real_drive,
    real_runs,
    window_limits,
)
from radar_odom_export.train import TrainConfig, train  # noqa: E402

pytestmark = pytest.mark.torch
DRIVE = "radiate-2019-02-12-edinburgh"


def _drive(rel, frames=None):
    rel = np.asarray(rel, dtype=np.float32)
    n = len(rel) + 1 if frames is None else frames
    rng = np.random.default_rng(0)
    images = rng.random((n, TINY.width_px, TINY.width_px)).astype(np.float16)
    return D.Drive("toy-real", images, rel)


def test_skip_pairs_compose_the_relative_poses_and_stop_at_the_window():
    max_t, max_yaw = window_limits(TINY)
    step = (0.9 * max_t / 2.5, 0.1, 0.3 * max_yaw / 2.5)  # 2 steps fit the window, 3 do not
    rel = np.tile(step, (6, 1))
    pairs = SkipPairs([_drive(rel)], TINY, max_skip=4)
    skips = sorted({b - a for _, a, b in pairs.index})
    assert skips == [1, 2]  # 3 steps move 1.08 × the window's reach
    absolute = chain_relative(rel)
    for (_, a, b), pose in zip(pairs.index, pairs.poses):
        np.testing.assert_allclose(pose, to_xyyaw(invert(absolute[a]) @ absolute[b]), atol=1e-5)
    assert len(pairs) == 6 + 5


def test_a_pair_without_a_reference_breaks_the_chains_through_it():
    rel = np.tile((0.5, 0.0, 0.0), (5, 1))
    rel[2] = np.nan
    pairs = SkipPairs([_drive(rel)], TINY, max_skip=4)
    assert all(not (a <= 2 < b) for _, a, b in pairs.index)
    assert {(a, b) for _, a, b in pairs.index} == {(0, 1), (0, 2), (1, 2), (3, 4), (3, 5), (4, 5)}


def test_gain_floor_keeps_empty_pixels_empty_and_stays_in_range():
    img = np.zeros((8, 8), np.float32)
    img[2:5, 3:6] = 0.6
    out = GainFloor()(np.random.default_rng(1), img)
    assert np.all(out[img == 0] == 0) and out.max() <= 1.0 and out.min() >= 0.0
    draws = {float(GainFloor()(np.random.default_rng(s), img)[3, 4]) for s in range(20)}
    assert len(draws) > 10  # it does randomise


def test_mixed_pairs_hold_the_asked_share_of_real_pairs_reproducibly():
    sim = D.PairDataset([D.toy_drive(TINY, 40, 1)])
    real = SkipPairs([_drive(np.tile((0.5, 0.0, 0.0), (5, 1)))], TINY, max_skip=1)
    mixed = MixedPairs(sim, real, 0.25, seed=3)
    n_real = 0
    for epoch in range(40):
        mixed.set_epoch(epoch)
        # the simulated set is not augmented here: an item that differs from sim[i] is a real pair
        n_real += sum(1 for i in range(len(mixed)) if not np.array_equal(mixed[i]["prev"], sim[i]["prev"]))
    share = n_real / (40 * len(mixed))
    assert 0.2 < share < 0.3, share
    mixed.set_epoch(7)
    a = [mixed[i]["pose"].copy() for i in range(len(mixed))]
    b = [mixed[i]["pose"].copy() for i in range(len(mixed))]
    np.testing.assert_array_equal(np.stack(a), np.stack(b))
    with pytest.raises(ValueError, match="real_fraction"):
        MixedPairs(sim, real, 1.5)


def test_training_mixes_real_pairs_in_and_records_them(tmp_path):
    sim_train, sim_val = [D.toy_drive(TINY, 8, s) for s in (1, 2)], [D.toy_drive(TINY, 6, 3)]
    real = _drive(np.tile((0.5, 0.0, 0.0), (7, 1)))  # skips of 1-3 fit the ±1.6 m reach: 7 + 6 + 5 pairs
    cfg = TrainConfig(output=str(tmp_path / "m.pt"), profile=TINY, epochs=1, batch=4, threads=1)
    summary = train(cfg, sim_train, sim_val, real_drives=[real])
    assert summary["real_drives"] == ["toy-real"] and summary["real_pairs"] == 18
    assert summary["steps"] == 14 // 4  # an epoch is still a pass over the simulated pairs


@pytest.mark.real
@pytest.mark.slow
def test_the_held_out_stretch_of_the_shared_drive_is_never_a_training_pair(real_data_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path))
    profile = get_profile("cart-0.4")  # its ±7.6 m window holds the skips of a car at 10 m/s
    drive = real_drive(real_data_dir / DRIVE, profile, holdout=80)
    assert drive.images.shape[0] == 200 and drive.poses_rel.shape == (199, 3)
    assert np.isfinite(drive.poses_rel).all()
    # the reference: ≈ 445 m over the 280 sweeps, of which the first 200 cover ≈ 340 m
    assert 300 < np.linalg.norm(drive.poses_rel[:, :2], axis=1).sum() < 380
    pairs = SkipPairs([drive], profile, max_skip=4)
    assert max(b for _, _, b in pairs.index) == 199 and len(pairs) > 3 * 199


@pytest.mark.real
def test_the_real_mask_figure_draws_a_held_out_sweep(real_data_dir, tmp_path):
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    from fixtures import load_script

    mod = load_script("examples/real_mask_figure.py")
    out = tmp_path / "mask.png"
    ckpt = root / "export" / "radar_odom_export" / "checkpoints" / "cart-0.4.pt"
    assert mod.main([str(ckpt), "-o", str(out), "--drive", str(real_data_dir / DRIVE), "--sweep", "240"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_real_runs_cut_at_pairs_without_a_reference_and_are_named_for_the_weights(monkeypatch):
    """`real_runs`: every run holds only pairs with a reference, sweeps and poses line up, the
    names carry the ``real:`` prefix that `calibrate.pair_weights` looks for."""
    from radar_odom_export import calibrate as cal
    from radar_odom_export import real_pairs as RP

    rel = np.tile((0.5, 0.0, 0.01), (7, 1)).astype(np.float32)
    rel[2] = np.nan
    toy = _drive(rel)
    monkeypatch.setattr(RP, "real_drive", lambda path, profile, holdout, use_cache=True: toy)
    runs = real_runs("somewhere/drive", TINY, holdout=0)
    assert [r.name for r in runs] == ["real:drive-0", "real:drive-3"]
    assert [r.num_pairs for r in runs] == [2, 4] and [len(r.images) for r in runs] == [3, 5]
    assert all(np.all(np.isfinite(r.poses_rel)) for r in runs)
    np.testing.assert_array_equal(runs[1].images[0], toy.images[3])
    assert cal.pair_weights([r.name for r in runs] + ["urban-7"], 0.5) == pytest.approx([0.25, 0.25, 0.5])
