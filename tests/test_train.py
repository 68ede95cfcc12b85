"""Training, baselines, checkpoints, augmentation, calibration and evaluation (export side)."""
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_odom.profiles import GridProfile  # noqa: E402
from radar_odom_export import calibrate as cal  # noqa: E402
from radar_odom_export import data as D  # noqa: E402
from radar_odom_export.checkpoint import (  # noqa: E402
    FORMAT,
    CheckpointError,
    load_checkpoint,
    read_checkpoint_dict,
    save_checkpoint,
)
from radar_odom_export.correlation import candidate_poses  # noqa: E402
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.softargmax import hard_argmax  # noqa: E402
from radar_odom_export.train import (  # noqa: E402
    Objective,
    TrainConfig,
    log_path,
    plot_path,
    pose_loss,
    state_path,
    train,
)

pytestmark = pytest.mark.torch

TINY = GridProfile("tiny", resolution_m=1.6, width_px=64, max_translation_m=4, rotation_range_rad=0.05,
                   rotation_step_rad=0.025, unet_base_channels=4, unet_depth=3)
# finer search for the augmentation checks: ±6 cells, ±4 rotation steps
FINE = GridProfile("fine", resolution_m=1.0, width_px=64, max_translation_m=6, rotation_range_rad=0.1,
                   rotation_step_rad=0.025, unet_base_channels=4, unet_depth=3)


@pytest.fixture(autouse=True)
def _one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="module")
def toy():
    return [D.toy_drive(TINY, 8, seed) for seed in (1, 2)], [D.toy_drive(TINY, 6, 3)]


def _batch(drive, with_labels=False):
    ds = D.PairDataset([drive], with_labels=with_labels)
    items = [ds[i] for i in range(len(ds))]
    return {k: torch.as_tensor(np.stack([it[k] for it in items])) for k in items[0]}


# ----------------------------------------------------------------------------- losses and steps
def test_pose_loss_counts_grid_cells():
    gt = torch.zeros(2, 3)
    pred = torch.tensor([[TINY.resolution_m, 0.0, 0.0], [0.0, 0.0, 2 * TINY.rotation_step_rad]])
    # one cell of x error -> 1; two rotation steps -> 4·yaw_weight; mean over the batch
    assert float(pose_loss(pred, gt, TINY)) == pytest.approx((1 + 4) / 2)
    assert float(pose_loss(pred, gt, TINY, yaw_weight=0.5)) == pytest.approx((1 + 2) / 2)


def test_few_adam_steps_reduce_pose_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    batch = _batch(D.toy_drive(TINY, 9, 5, num_followers=40))
    # masks start nearly closed, so at β = 1 the tiny volumes are flat and the first steps
    # crawl; β = 10 gives a weight distribution the gradient can shape from step one
    obj = Objective(MaskedCorrelator(TINY.with_(beta_pose=10.0)), "pose", 1.0)
    opt = torch.optim.Adam(obj.parameters(), lr=3e-3)
    losses = []
    for _ in range(12):
        loss, _ = obj(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.95 * losses[0], losses


def test_pose_target_spreads_the_true_pose_over_neighbouring_candidates():
    from radar_odom_export.train import pose_target

    n, kc = TINY.translation_cells, TINY.num_rotations // 2
    res, step = TINY.resolution_m, TINY.rotation_step_rad
    gt = torch.tensor([[res, -2 * res, step],  # exactly on a candidate
                       [0.5 * res, 0.0, 0.0],  # halfway between x cells 0 and 1
                       [100.0, 0.0, -1.0]],  # outside the window: clamped to the border
                      dtype=torch.float64)
    t = pose_target(gt, TINY)
    assert t.shape == (3, TINY.num_rotations, 2 * n + 1, 2 * n + 1)
    torch.testing.assert_close(t.sum(dim=(1, 2, 3)), torch.ones(3, dtype=torch.float64))
    assert t[0, kc + 1, n + 1, n - 2] == 1.0
    assert t[1, kc, n, n] == pytest.approx(0.5) and t[1, kc, n + 1, n] == pytest.approx(0.5)
    assert t[2, 0, 2 * n, n] == 1.0
    cand = candidate_poses(TINY, torch.float64)
    mean = (t.unsqueeze(-1) * cand.unsqueeze(0)).sum(dim=(1, 2, 3))
    torch.testing.assert_close(mean[:2], gt[:2])  # trilinear weights keep the mean exact


def test_cross_entropy_steps_reduce_pose_error_on_a_fixed_batch():
    torch.manual_seed(0)
    batch = _batch(D.toy_drive(TINY, 9, 5, num_followers=40))
    obj = Objective(MaskedCorrelator(TINY.with_(beta_pose=10.0)), "pose", 1.0, pose_loss_kind="ce")
    opt = torch.optim.Adam(obj.parameters(), lr=3e-3)
    ce, mse = [], []
    for _ in range(12):
        loss, m = obj(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        ce.append(float(loss.detach()))
        mse.append(float(m.detach()))
    assert ce[-1] < 0.95 * ce[0] and mse[-1] < mse[0], (ce, mse)


def test_supervised_masks_train_on_static_labels():
    torch.manual_seed(0)
    batch = _batch(D.toy_drive(TINY, 6, 7), with_labels=True)
    model = MaskedCorrelator(TINY)
    obj = Objective(model, "masks", 1.0)
    opt = torch.optim.Adam(obj.parameters(), lr=1e-2)
    for _ in range(30):
        loss, _ = obj(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
    # better than the best constant mask (the label prior p): BCE below the entropy H(p)
    p = float(torch.cat([batch["label_prev"], batch["label_cur"]]).mean())
    prior_bce = -(p * math.log(p) + (1 - p) * math.log(1 - p))
    assert float(obj(batch)[0].detach()) < 0.9 * prior_bce
    # and the masks tell static cells from the rest
    with torch.no_grad():
        m = model.mask(batch["prev"])
    lab = batch["label_prev"] > 0.5
    assert float(m[lab].mean()) > 1.5 * float(m[~lab].mean())


# ----------------------------------------------------------------------------- train(): files, resume, baselines
def _cfg(tmp_path, name="m.pt", **kw):
    kw.setdefault("epochs", 1)
    kw.setdefault("batch", 4)
    kw.setdefault("threads", 1)
    return TrainConfig(output=str(tmp_path / name), profile=TINY, **kw)


def test_train_writes_checkpoint_state_log_and_plot(tmp_path, toy):
    tr, va = toy
    summary = train(_cfg(tmp_path, epochs=2, info={"command": "test"}), tr, va)
    out = tmp_path / "m.pt"
    for p in (out, state_path(out), log_path(out), plot_path(out)):
        assert p.is_file(), p
    assert summary["epochs_run"] == 2 and summary["steps"] == 2 * (14 // 4)
    raw = torch.load(out, weights_only=True)  # plain values only
    assert raw["format"] == FORMAT and raw["masking"] == "learned"
    assert raw["train"]["command"] == "test" and raw["train"]["best_epoch"] in (1, 2)
    log = json.loads(log_path(out).read_text())
    assert [e["epoch"] for e in log["epochs"]] == [1, 2]
    assert math.isfinite(log["epochs"][-1]["val_loss"])


def test_resume_continues_from_the_saved_epoch_and_matches_an_uninterrupted_run(tmp_path, toy):
    tr, va = toy
    train(_cfg(tmp_path, "a.pt", epochs=2), tr, va)
    train(_cfg(tmp_path, "b.pt", epochs=1), tr, va)
    st = torch.load(state_path(tmp_path / "b.pt"), weights_only=True)
    assert st["epoch"] == 1
    summary = train(_cfg(tmp_path, "b.pt", epochs=2, resume=True), tr, va)
    assert summary["epochs_run"] == 2
    log = json.loads(log_path(tmp_path / "b.pt").read_text())
    assert [e["epoch"] for e in log["epochs"]] == [1, 2]
    a = torch.load(state_path(tmp_path / "a.pt"), weights_only=True)["model"]
    b = torch.load(state_path(tmp_path / "b.pt"), weights_only=True)["model"]
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-5, atol=1e-6)


def test_resume_refuses_missing_state_or_other_profile(tmp_path, toy):
    tr, va = toy
    with pytest.raises(CheckpointError, match="no resume state"):
        train(_cfg(tmp_path, "c.pt", resume=True), tr, va)
    train(_cfg(tmp_path, "c.pt"), tr, va)
    other = TrainConfig(output=str(tmp_path / "c.pt"), profile=TINY.with_(unet_base_channels=2), epochs=2,
                        batch=4, threads=1, resume=True)
    with pytest.raises(CheckpointError, match="same settings"):
        train(other, tr, va)


def test_init_from_starts_at_another_checkpoints_weights(tmp_path, toy):
    tr, va = toy
    torch.manual_seed(5)
    src = save_checkpoint(tmp_path / "src.pt", MaskedCorrelator(TINY), "learned")
    # lr 0: the weights after training are exactly the ones loaded
    train(_cfg(tmp_path, "dst.pt", lr=0.0, init_from=str(src)), tr, va)
    a = torch.load(src, weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "dst.pt", weights_only=True)
    assert b["train"]["init_from"] == src.name  # the file name only: no build-machine paths
    for k in a:
        torch.testing.assert_close(a[k], b["state_dict"][k])
    other = TrainConfig(output=str(tmp_path / "x.pt"), profile=TINY.with_(unet_base_channels=2), epochs=1,
                        batch=4, threads=1, init_from=str(src))
    with pytest.raises(CheckpointError, match="do not fit"):
        train(other, tr, va)


def test_raw_baseline_is_a_checkpoint_without_weights(tmp_path, toy):
    tr, va = toy
    summary = train(_cfg(tmp_path, "raw.pt", masking="raw"), tr, va)
    ckpt = torch.load(tmp_path / "raw.pt", weights_only=True)
    assert ckpt["masking"] == "raw" and ckpt["state_dict"] == {}
    assert math.isfinite(summary["best_val"]) and not state_path(tmp_path / "raw.pt").exists()
    model, meta = load_checkpoint(tmp_path / "raw.pt")
    assert meta["profile"] == TINY and model.masker is None


def test_supervised_mask_training_needs_labels(tmp_path, toy):
    tr, va = toy
    train(_cfg(tmp_path, "s.pt", supervised_masks=True), tr, va)
    assert torch.load(tmp_path / "s.pt", weights_only=True)["train"]["objective"] == "masks"
    unlabelled = [D.Drive("rec", tr[0].images, tr[0].poses_rel)]
    with pytest.raises(D.SequenceError, match="labels"):
        train(_cfg(tmp_path, "s2.pt", supervised_masks=True), unlabelled, va)


# ----------------------------------------------------------------------------- checkpoints
def test_checkpoint_round_trip_with_weights_only(tmp_path):
    torch.manual_seed(1)
    model = MaskedCorrelator(TINY)
    train = {"seeds": np.arange(3), "wall_s": np.float32(2.5)}
    path = save_checkpoint(tmp_path / "m.pt", model, "learned", train=train)
    raw = torch.load(path, weights_only=True)
    assert raw["train"] == {"seeds": [0, 1, 2], "wall_s": 2.5}
    assert set(raw["state_dict"]) == set(dict(model.named_parameters()))  # weights only, no grids
    loaded, meta = load_checkpoint(path)
    assert meta["profile"] == TINY and meta["masking"] == "learned"
    x = torch.rand(2, 64, 64)
    with torch.no_grad():
        for a, b in zip(model(x[:1], x[1:]), loaded(x[:1], x[1:])):
            torch.testing.assert_close(a, b)


class _Evil:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))  # would create the marker file if unpickled


def test_malicious_or_odd_checkpoints_are_refused(tmp_path):
    marker = tmp_path / "pwned"
    evil = tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "payload": _Evil(str(marker))}, evil)
    with pytest.raises(CheckpointError, match="not a radar-odom checkpoint"):
        load_checkpoint(evil)
    assert not marker.exists()

    good = torch.load(save_checkpoint(tmp_path / "g.pt", MaskedCorrelator(TINY), "learned"), weights_only=True)
    cases = {
        "format": ({**good, "format": "something/2"}, "expected"),
        "notdict": ([1, 2, 3], "format is 'list'"),
        "missing": ({k: v for k, v in good.items() if k != "profile"}, "'profile'"),
        "masking": ({**good, "masking": "magic"}, "masking"),
        "shapes": ({**good, "state_dict": {k: v[..., :1] for k, v in good["state_dict"].items()}}, "do not fit"),
        "profile": ({**good, "profile": {**good["profile"], "width_px": 3}}, "invalid profile"),
    }
    for name, (obj, msg) in cases.items():
        p = tmp_path / f"{name}.pt"
        torch.save(obj, p)
        with pytest.raises(CheckpointError, match=msg):
            load_checkpoint(p)
    trunc = tmp_path / "trunc.pt"
    trunc.write_bytes((tmp_path / "g.pt").read_bytes()[:100])
    with pytest.raises(CheckpointError):
        read_checkpoint_dict(trunc)
    with pytest.raises(CheckpointError, match="no such"):
        read_checkpoint_dict(tmp_path / "absent.pt")


# ----------------------------------------------------------------------------- augmentation
def _render_pair(profile, pose, seed=0, n=120):
    """(prev, cur) images of random static reflectors; ``pose`` = cur's frame in prev's."""
    rng = np.random.default_rng(seed)
    pts_prev = rng.uniform(-0.9 * profile.extent_m, 0.9 * profile.extent_m, (n, 2))
    w = rng.uniform(0.5, 1.0, n)
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    # q (cur frame) = R(yaw)ᵀ (p − t)
    d = pts_prev - np.array([x, y])
    pts_cur = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    r = lambda p: D.render_points(p, w, profile.resolution_m, profile.width_px, sigma_px=1.0)  # noqa: E731
    return r(pts_prev), r(pts_cur)


def _argmax_pose(prev, cur, profile=FINE):
    model = MaskedCorrelator(profile, masking="raw")
    with torch.no_grad():
        v = model.correlation_volume(
            torch.from_numpy(np.ascontiguousarray(prev))[None], torch.from_numpy(np.ascontiguousarray(cur))[None]
        )
    return hard_argmax(v, model.candidates)[0].numpy()


def _close(est, want, profile=FINE):
    return (
        abs(est[0] - want[0]) <= 0.75 * profile.resolution_m
        and abs(est[1] - want[1]) <= 0.75 * profile.resolution_m
        and abs(est[2] - want[2]) <= 0.75 * profile.rotation_step_rad
    )


# yaws are 0 or >= 2 rotation steps: a yaw one step from 0 ties with the yaw-0 slice, the only
# candidate not bilinearly resampled (resampling blurs sharp targets and lowers their score)
POSES = [(3.0, 2.0, 0.05), (-2.0, -3.0, -0.075), (4.0, -1.0, 0.0)]


@pytest.mark.parametrize("pose", POSES)
def test_raw_argmax_recovers_the_rendered_pose(pose):
    prev, cur = _render_pair(FINE, pose)
    assert _close(_argmax_pose(prev, cur), pose)


@pytest.mark.parametrize("pose", POSES)
def test_mirror_swap_rotate_keep_labels_exact(pose):
    prev, cur = _render_pair(FINE, pose, seed=1)
    pose = np.array(pose, np.float32)
    for name, aug in (
        ("mirror", lambda a, b, p: D.mirror_pair(a, b, p)),
        ("swap", lambda a, b, p: D.swap_pair(a, b, p)),
        ("rotate", lambda a, b, p: D.rotate_pair(a, b, p, 0.6)),
    ):
        a2, b2, p2, _ = aug(prev, cur, pose)
        est = _argmax_pose(a2, b2)
        assert _close(est, p2), (name, est, p2)
        assert not _close(est, pose), (name, "augmentation changed nothing measurable")


def test_augmentations_are_involutions_and_transform_labels():
    rng = np.random.default_rng(0)
    a, b = rng.random((2, 16, 16)).astype(np.float32)
    la, lb = (a > 0.5).astype(np.float32), (b > 0.5).astype(np.float32)
    pose = np.array([2.0, 0.5, 0.1], np.float32)
    a2, b2, p2, (la2, lb2) = D.mirror_pair(*D.mirror_pair(a, b, pose, (la, lb)))
    np.testing.assert_array_equal(a2, a)
    np.testing.assert_array_equal(la2, la)
    np.testing.assert_allclose(p2, pose)
    a2, b2, p2, (la2, lb2) = D.swap_pair(a, b, pose, (la, lb))
    assert a2 is b and la2 is lb
    np.testing.assert_allclose(D.swap_pair(a2, b2, p2)[2], pose, atol=1e-6)


def test_rotation_moves_a_point_target_to_the_rotated_position():
    res, w = 0.5, 65
    img = D.render_points(np.array([[10.0, 0.0]]), np.ones(1), res, w, sigma_px=1.0)
    phi = math.pi / 2  # x forward rotates onto +y (right)
    out = D.rotate_image(img, phi)
    r, c = np.unravel_index(np.argmax(out), out.shape)
    cw = (w - 1) / 2
    assert ((cw - r) * res, (c - cw) * res) == pytest.approx((0.0, 10.0), abs=1e-9)


def test_augment_draws_are_reproducible_per_epoch_and_index(toy):
    tr, _ = toy
    ds = D.PairDataset(tr, augment=D.Augment(0.5, 0.5, 0.3), seed=4)
    ds.set_epoch(3)
    a, b = ds[5], ds[5]
    np.testing.assert_array_equal(a["prev"], b["prev"])
    poses = set()
    for e in range(8):
        ds.set_epoch(e)
        poses.add(tuple(np.round(ds[5]["pose"], 5)))
    assert len(poses) > 1


# ----------------------------------------------------------------------------- data plumbing
def test_seed_parsing_and_policy():
    assert D.parse_seeds("1000-1003,1010") == [1000, 1001, 1002, 1003, 1010]
    assert D.parse_seeds("7") == [7]
    with pytest.raises(ValueError):
        D.parse_seeds("5-3")
    D.check_seed_policy([1000, 1999], "train")
    D.check_seed_policy([5000, 9999], "eval")
    for seeds, use in (([999], "train"), ([1500], "val"), ([2000], "eval"), ([100], "test")):
        with pytest.raises(ValueError, match="seed policy"):
            D.check_seed_policy(seeds, use)


def test_pairs_never_cross_drives_and_split_is_by_drive(toy):
    tr, va = toy
    ds = D.PairDataset(tr)
    assert len(ds) == sum(d.num_pairs for d in tr) == 14
    item = ds[7]  # first pair of the second drive
    np.testing.assert_array_equal(item["prev"], tr[1].images[0].astype(np.float32))
    np.testing.assert_array_equal(item["pose"], tr[1].poses_rel[0])
    train_d, val_d = D.split_by_drive(tr + va)
    assert [d.name for d in val_d] == [va[0].name]
    head, tail = D.split_by_drive([tr[0]])
    assert head[0].num_pairs + tail[0].num_pairs == tr[0].num_pairs - 1  # the cut pair is dropped
    np.testing.assert_array_equal(tail[0].images[0], tr[0].images[len(head[0].images)])


def test_drive_cache_is_float16_npz_outside_the_repo(tmp_path, monkeypatch):
    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    calls = []

    def fake(profile, spec):
        calls.append(spec)
        return D.toy_drive(profile, spec.frames, spec.seed, name=spec.name)

    monkeypatch.setattr(D, "simulate_drive_arrays", fake)
    specs = D.sim_specs([11, 12], ["urban"], 5)
    first = D.build_drives(TINY, specs, workers=1)
    again = D.build_drives(TINY, specs, workers=1)
    assert len(calls) == 2  # the second call read the cache
    files = sorted((tmp_path / "cache" / "drives").glob("*.npz"))
    assert len(files) == 2 and all("tiny" in f.name and "urban_s1" in f.name for f in files)
    with np.load(files[0]) as z:
        assert z["images"].dtype == np.float16 and z["labels"].dtype == np.float16
    np.testing.assert_array_equal(first[1].images, again[1].images)
    assert again[0].name == "urban-11"
    # another grid with the same name must not reuse the cache
    D.build_drives(TINY.with_(resolution_m=1.5), specs[:1], workers=1)
    assert len(calls) == 3


# ----------------------------------------------------------------------------- calibration
def test_calibrate_beta_finds_the_known_temperature():
    beta_star = 0.37
    res = cal.calibrate_beta(lambda b: 3.0 * (b / beta_star) ** 2, beta0=1.0)
    assert 2.7 <= res.mean_d2 <= 3.3
    assert res.beta_cov == pytest.approx(beta_star, rel=0.05)
    assert len(res.table) >= 5 and res.table == sorted(res.table)
    with pytest.raises(cal.CalibrationError, match="never crosses"):
        cal.calibrate_beta(lambda b: 0.5, beta0=1.0, max_decades=6)


def test_calibration_on_gaussian_volumes_moves_mean_d2_into_the_band():
    """Volumes whose softmax at β is a Gaussian of covariance S/β, errors drawn from S/β*."""
    prof = GridProfile(
        "cal",
        resolution_m=1.0,
        width_px=64,
        max_translation_m=10,
        rotation_range_rad=0.25,
        rotation_step_rad=0.025,
        unet_depth=3,
    )
    cand = candidate_poses(prof, torch.float64)
    rng = np.random.default_rng(0)
    s = np.diag([2.0**2, 1.5**2, 0.05**2])  # spread of the unit-temperature Gaussian
    s_inv = np.linalg.inv(s)
    beta_true = 2.5  # the errors match softmax(β C) at this β
    n = 250
    mu = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(-0.05, 0.05, n)])
    gt = mu + rng.multivariate_normal(np.zeros(3), s / beta_true, n)
    diff = cand.numpy()[None] - mu[:, None, None, None, :]
    vol = -0.5 * np.einsum("...i,ij,...j->...", diff, s_inv, diff)
    curve = cal.D2Curve(torch.from_numpy(vol).float(), gt, cand, prof.with_(beta_pose=1.0))
    assert curve(1.0) < 2.0 < 4.0 < curve(10.0)  # uncalibrated at beta_pose, too confident later
    res = cal.calibrate_beta(curve, beta0=1.0)
    assert 2.7 <= res.mean_d2 <= 3.3
    assert res.beta_cov == pytest.approx(beta_true, rel=0.2)


def test_mahalanobis_jitter_keeps_a_collapsed_covariance_finite():
    err = np.array([[0.1, 0.0, 0.0]])
    d2 = cal.mahalanobis_sq(err, np.zeros((1, 3, 3)), cal.covariance_jitter(TINY))
    assert np.isfinite(d2).all() and d2[0] == pytest.approx(0.1**2 / (1e-3 * TINY.resolution_m) ** 2)
    assert cal.pose_errors(np.array([[0, 0, 3.1]]), np.array([[0, 0, -3.1]]))[0, 2] == pytest.approx(6.2 - 2 * math.pi)


def test_calibrate_checkpoint_writes_beta_cov(tmp_path):
    drives = [D.toy_drive(TINY, 30, s, noise=0.3) for s in (21, 22)]
    path = save_checkpoint(tmp_path / "raw.pt", MaskedCorrelator(TINY, masking="raw"), "raw")
    res = cal.calibrate_checkpoint(path, drives, output=tmp_path / "cal.pt")
    assert 2.7 <= res.mean_d2 <= 3.3 and res.pairs == 58
    model, meta = load_checkpoint(tmp_path / "cal.pt")
    assert meta["profile"].beta_cov == pytest.approx(res.beta_cov)
    assert meta["calibration"]["mean_d2"] == pytest.approx(res.mean_d2)
    assert load_checkpoint(path)[1]["profile"].beta_cov == 1.0  # -o leaves the input alone


def test_calibrate_sets_the_pose_estimator_and_reports_each_scenario(tmp_path):
    drives = [D.toy_drive(TINY, 30, s, noise=0.3, name=f"{sc}-{s}") for s, sc in ((21, "urban"), (22, "open"))]
    path = save_checkpoint(tmp_path / "raw.pt", MaskedCorrelator(TINY, masking="raw"), "raw")
    res = cal.calibrate_checkpoint(path, drives, output=tmp_path / "cal.pt", pose_estimator="parabolic")
    assert 2.7 <= res.mean_d2 <= 3.3
    rows = {ln.split("|")[1].strip(): ln for ln in res.scenario_table.splitlines()[2:]}
    assert set(rows) == {"urban", "open", "all"} and all("| 29 |" in rows[k] for k in ("urban", "open"))
    assert "| 58 |" in rows["all"]
    _, meta = load_checkpoint(tmp_path / "cal.pt")
    assert meta["profile"].pose_estimator == "parabolic"
    assert meta["calibration"]["per_scenario"] == res.scenario_table


def test_fit_covariance_shape_recovers_a_known_scale_and_floors():
    """Errors drawn from s·M + floors, with moments ranging from none (a sharp peak: the floor
    alone) to large (a ridge along x): the fit finds s and both floors, mean d² ≈ 3."""
    rng = np.random.default_rng(3)
    prof = TINY
    n = 4000
    size = np.exp(rng.uniform(np.log(1e-4), np.log(4.0), n))  # m², from sharp to a long ridge
    moments = np.zeros((n, 3, 3))
    moments[:, 0, 0] = size
    moments[:, 1, 1] = 0.05 * size
    moments[:, 2, 2] = 1e-3 * size
    truth = prof.with_(cov_scale=2.5, cov_floor_cells=0.2, cov_floor_yaw_cells=0.4)
    cov = cal.shape_covariances(moments, truth)
    errors = np.einsum("pij,pj->pi", np.linalg.cholesky(cov), rng.standard_normal((n, 3)))
    shape = cal.fit_covariance_shape(moments, errors, prof)
    assert shape.cov_scale == pytest.approx(2.5, rel=0.1)
    assert shape.cov_floor_cells == pytest.approx(0.2, rel=0.1)
    assert shape.cov_floor_yaw_cells == pytest.approx(0.4, rel=0.1)
    assert shape.mean_d2 == pytest.approx(3.0, rel=0.02) and shape.pairs == n
    # the paper's form (scale 1, a whole cell's floor) is far off on these errors: too wide for
    # the sharp peaks, too narrow for the ridges; the fit is right for both
    jit = cal.covariance_jitter(prof)
    d2_paper = cal.mahalanobis_sq(errors, cal.shape_covariances(moments, prof), jit)
    fitted = prof.with_(**shape.profile_fields())
    d2_fit = cal.mahalanobis_sq(errors, cal.shape_covariances(moments, fitted), jit)
    sharp, ridge = size < 1e-3, size > 1.0
    assert d2_paper[sharp].mean() < 0.5 and d2_paper[ridge].mean() > 5.0
    assert 2.5 < d2_fit[sharp].mean() < 3.5 and 2.5 < d2_fit[ridge].mean() < 3.5
    with pytest.raises(ValueError, match="moments"):
        cal.fit_covariance_shape(moments[:, :2, :2], errors, prof)


def test_weighted_shape_fit_follows_the_weighted_group_and_pair_weights_split_the_shares():
    """Two groups drawn with different floors (a sharp-peaked 'simulated' one, a noisier 'real'
    one): weight 0 on a group removes it from the fit (same result as fitting the other alone),
    equal weights land between, and the weighted mean d² is 3 at the optimum."""
    rng = np.random.default_rng(5)
    prof = TINY
    n = 3000
    size = np.exp(rng.uniform(np.log(1e-4), np.log(1.0), n))
    moments = np.zeros((n, 3, 3))
    moments[:, 0, 0], moments[:, 1, 1], moments[:, 2, 2] = size, 0.05 * size, 1e-3 * size

    def draw(truth):
        cov = cal.shape_covariances(moments, truth)
        return np.einsum("pij,pj->pi", np.linalg.cholesky(cov), rng.standard_normal((n, 3)))

    sim = draw(prof.with_(cov_scale=2.0, cov_floor_cells=0.2, cov_floor_yaw_cells=0.4))
    real = draw(prof.with_(cov_scale=2.0, cov_floor_cells=0.8, cov_floor_yaw_cells=3.0))
    m2, e2 = np.concatenate([moments, moments]), np.concatenate([sim, real])
    names = [f"urban-{k}" for k in range(n)] + ["real:drive-0"] * n
    alone = cal.fit_covariance_shape(moments, real, prof)
    only_real = cal.fit_covariance_shape(m2, e2, prof, weights=cal.pair_weights(names, 1.0))
    assert (only_real.cov_floor_cells, only_real.cov_floor_yaw_cells) == pytest.approx(
        (alone.cov_floor_cells, alone.cov_floor_yaw_cells), rel=1e-3)
    assert only_real.cov_floor_yaw_cells == pytest.approx(3.0, rel=0.1)
    only_sim = cal.fit_covariance_shape(m2, e2, prof, weights=cal.pair_weights(names, 0.0))
    assert only_sim.cov_floor_yaw_cells == pytest.approx(0.4, rel=0.15)
    half = cal.fit_covariance_shape(m2, e2, prof, weights=cal.pair_weights(names, 0.5))
    assert only_sim.cov_floor_yaw_cells < half.cov_floor_yaw_cells < only_real.cov_floor_yaw_cells
    assert half.mean_d2 == pytest.approx(3.0, rel=0.02)
    # the shares: real pairs carry real_share, equal within each group; one group alone: equal weights
    w = cal.pair_weights(["urban-1", "open-2", "real:x-0"], 0.25)
    assert w == pytest.approx([0.375, 0.375, 0.25])
    assert cal.pair_weights(["urban-1", "open-2"], 0.25) == pytest.approx([0.5, 0.5])
    with pytest.raises(ValueError, match="real_share"):
        cal.pair_weights(names, 1.5)
    with pytest.raises(ValueError, match="weights"):
        cal.fit_covariance_shape(moments, real, prof, weights=-np.ones(n))


def test_calibration_provenance_carries_no_build_machine_paths():
    cmd = cal.provenance_command(["calibrate", "/home/me/runs/cart-0.4.pt", "--sim-seeds", "2500-2503",
                                  "-o", "/tmp/x y/cal.pt", "rel/dir/model.pt"])
    assert cmd == "radar-odom calibrate cart-0.4.pt --sim-seeds 2500-2503 -o cal.pt rel/dir/model.pt"


def test_calibrate_checkpoint_fits_the_shape_and_the_model_reports_it(tmp_path):
    drives = [D.toy_drive(TINY, 30, s, noise=0.3, name=f"urban-{s}") for s in (21, 22)]
    path = save_checkpoint(tmp_path / "raw.pt", MaskedCorrelator(TINY, masking="raw"), "raw")
    temp = cal.calibrate_checkpoint(path, drives, output=tmp_path / "t.pt", covariance="temperature")
    res = cal.calibrate_checkpoint(path, drives, output=tmp_path / "f.pt")
    assert temp.shape is None and res.shape is not None and res.beta_cov == pytest.approx(temp.beta_cov)
    assert res.mean_d2 == pytest.approx(3.0, rel=0.05) and res.pairs == 58
    model, meta = load_checkpoint(tmp_path / "f.pt")
    prof = meta["profile"]
    assert (prof.cov_scale, prof.cov_floor_cells, prof.cov_floor_yaw_cells) == pytest.approx(
        (res.shape.cov_scale, res.shape.cov_floor_cells, res.shape.cov_floor_yaw_cells))
    assert meta["calibration"]["shape"]["search"] == "exhaustive"
    assert load_checkpoint(tmp_path / "t.pt")[1]["profile"].cov_scale == 1.0
    # the calibrated model's own covariances give the fit's mean d²
    from radar_odom_export.evaluate import estimate_drive

    est = [estimate_drive(model.eval(), d.images) for d in drives]
    err = np.concatenate([cal.pose_errors(d.poses_rel, p) for d, (p, _) in zip(drives, est)])
    d2 = cal.mahalanobis_sq(err, np.concatenate([c for _, c in est]), cal.covariance_jitter(prof))
    assert d2.mean() == pytest.approx(res.mean_d2, rel=1e-3)


# ----------------------------------------------------------------------------- evaluation
def test_streamed_estimates_equal_the_pair_form():
    from radar_odom_export.evaluate import estimate_drive

    torch.manual_seed(0)
    model = MaskedCorrelator(TINY).eval()
    d = D.toy_drive(TINY, 11, 9)
    poses, covs = estimate_drive(model, d.images, batch=4)  # chunks 4+4+3: state crosses chunks
    x = torch.from_numpy(d.images.astype(np.float32))
    with torch.no_grad():
        p_ref, c_ref = model(x[:-1], x[1:])
    np.testing.assert_allclose(poses, p_ref.double().numpy(), atol=1e-5)
    np.testing.assert_allclose(covs, c_ref.double().numpy(), atol=1e-6)


def test_evaluate_model_reports_kitti_d2_and_runtime():
    from radar_odom_export.evaluate import evaluate_model, markdown_table

    model = MaskedCorrelator(TINY, masking="raw").eval()
    drives = [D.toy_drive(TINY, 40, s, name=f"toy-{s}") for s in (31, 32)]
    res = evaluate_model(model, drives, lengths=(20, 40), timing_repeats=3)
    assert res["kitti"]["step"] == 4 and res["pooling"] == "segments"
    assert 0 <= res["translation_percent"] < 100 and res["mean_d2"] > 0 and res["runtime_ms_per_pair"] > 0
    assert set(res["per_scenario"]) == {"toy"} and len(res["per_drive"]) == 2
    table = markdown_table([{**res, "label": "raw"}])
    assert table.splitlines()[2].startswith("| raw | 1.6 |")


# ----------------------------------------------------------------------------- recorded sequences + CLI
@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    from radar_odom.sim import SimConfig, write_drive

    root = tmp_path_factory.mktemp("rec")
    cfg = SimConfig().with_sensor(num_bins=800)  # 35 m of range: small files, fast
    return [write_drive(root / f"seq{s}", seed=s, frames=6, config=cfg, progress=False) for s in (41, 42)]


def test_recorded_sequence_becomes_a_drive_cut_at_missing_ground_truth(recordings, tmp_path, monkeypatch):
    import shutil

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    (drive,) = D.sequence_drives(recordings[0], TINY)
    assert drive.images.shape == (6, 64, 64) and drive.images.dtype == np.float16
    from radar_odom.io import read_sequence

    np.testing.assert_allclose(drive.poses_rel, read_sequence(recordings[0]).gt_relative, atol=1e-5)
    assert drive.path_length_m() > 1.0
    # drop the ground-truth row of pair 2 (sweeps 2 -> 3): sweeps 0..2 and 3..5 remain
    seq = tmp_path / "cut"
    shutil.copytree(recordings[0], seq)
    gt = seq / "gt" / "radar_odometry.csv"
    lines = gt.read_text().splitlines()
    gt.write_text("\n".join(lines[:3] + lines[4:]) + "\n")
    parts = D.sequence_drives(seq, TINY)
    assert [p.num_pairs for p in parts] == [2, 2] and parts[0].name == "cut[0]"


def test_cli_trains_on_recordings_holding_out_the_last_folder(recordings, tmp_path, monkeypatch):
    from dataclasses import asdict

    from radar_odom.commands.cli import main

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    prof = tmp_path / "tiny.json"
    prof.write_text(json.dumps(asdict(TINY)))
    out = tmp_path / "cli.pt"
    argv = [
        "train",
        *map(str, recordings),
        "-o",
        str(out),
        "--profile",
        str(prof),
        "--epochs",
        "1",
        "--batch",
        "2",
        "--threads",
        "1",
    ]
    assert main(argv) == 0
    _, meta = load_checkpoint(out)
    assert meta["train"]["train_drives"] == ["seq41"] and meta["train"]["val_drives"] == ["seq42"]
    assert meta["train"]["command"].startswith("radar-odom ")
    assert str(tmp_path) not in meta["train"]["command"]  # absolute paths cut to file names
    # recordings carry no static labels: the supervised-mask baseline says so
    argv[argv.index("-o") + 1] = str(tmp_path / "s.pt")
    assert main(argv + ["--supervised-masks"]) == 1


def test_cli_writes_a_cfar_checkpoint_without_training(recordings, tmp_path, monkeypatch):
    """`radar-odom train --masking cfar`: like raw, nothing trained, a weightless checkpoint that
    `radar-odom export` takes (tests/test_normalise.py exports one)."""
    from dataclasses import asdict

    from radar_odom.commands.cli import main

    monkeypatch.setenv("RADAR_ODOM_CACHE", str(tmp_path / "cache"))
    prof = tmp_path / "tiny.json"
    prof.write_text(json.dumps(asdict(TINY.with_(input_norm="floor-scale"))))
    out = tmp_path / "cfar.pt"
    args = ["train", *map(str, recordings), "--profile", str(prof), "--masking", "cfar",
            "--batch", "2", "--threads", "1"]
    assert main([*args, "-o", str(out)]) == 0
    model, meta = load_checkpoint(out)
    assert meta["masking"] == "cfar" and meta["train"]["steps"] == 0 and model.cfar is not None
    assert meta["profile"].input_norm == "floor-scale"
    # a profile without the normalisation is refused: CFAR thresholds are in normalised units
    prof.write_text(json.dumps(asdict(TINY)))
    assert main([*args, "-o", str(tmp_path / "x.pt")]) == 1


def test_cli_commands_need_torch_only_when_run():
    import subprocess
    import sys

    code = (
        "import sys, radar_odom.commands.cli as c; p = c.build_parser(); "
        "p.parse_args(['train', '-o', 'x.pt']); p.parse_args(['calibrate', 'x.pt']); "
        "assert not [m for m in sys.modules if m.split('.')[0] == 'torch']"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_symmetric_masker_trains_mirror_equivariant_and_saves_plain_weights(tmp_path, toy):
    """`--symmetric-masker` (issue 41): from a handed init, after optimiser steps the saved masker
    maps a left/right flipped sweep to the flipped mask, under the plain weight names, and the
    constraint survives a resume."""
    from radar_odom_export.checkpoint import model_from_dict
    from radar_odom_export.symmetry import is_left_right_symmetric

    tr, va = toy
    torch.manual_seed(7)
    src = save_checkpoint(tmp_path / "handed.pt", MaskedCorrelator(TINY), "learned")
    x = torch.rand(2, TINY.width_px, TINY.width_px)
    handed = load_checkpoint(src)[0]
    with torch.no_grad():
        assert not torch.allclose(handed.mask(x.flip(-1)), handed.mask(x).flip(-1), atol=1e-4)
    # two epochs in one run: a checkpoint saved mid-run must leave the constrained model training
    cfg = _cfg(tmp_path, "sym.pt", lr=1e-2, epochs=2, init_from=str(src), symmetric_masker=True)
    train(cfg, tr, va)
    with pytest.raises(CheckpointError, match="with --symmetric-masker"):
        train(_cfg(tmp_path, "sym.pt", epochs=3, resume=True), tr, va)  # said, not a state_dict key dump
    train(_cfg(tmp_path, "sym.pt", lr=1e-2, epochs=3, resume=True, init_from=str(src), symmetric_masker=True), tr, va)
    ckpt = read_checkpoint_dict(tmp_path / "sym.pt")
    assert ckpt["train"]["init_from"] == src.name  # the resume's record still says where it started
    assert ckpt["train"]["symmetric_masker"] is True and "masker_symmetry" in ckpt["train"]
    assert set(ckpt["state_dict"]) == set(torch.load(src, weights_only=True)["state_dict"])  # plain names
    model = model_from_dict(ckpt).eval()
    assert is_left_right_symmetric(model.masker)
    start = load_checkpoint(src)[0].masker.state_dict()
    moved = [k for k, v in model.masker.state_dict().items()
             if k.endswith("weight") and not torch.allclose(v, 0.5 * (start[k] + start[k].flip(-1)))]
    assert moved  # the steps changed the kernels, not just symmetrised them
    with torch.no_grad():
        torch.testing.assert_close(model.mask(x.flip(-1)), model.mask(x).flip(-1), atol=1e-5, rtol=0)
