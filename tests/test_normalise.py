"""Input normalisation (``input_norm="floor-scale"``) and the training-free CFAR masking:
gain/offset invariance, range-dependent floor removal, degenerate sweeps, gradients, the
profile field, and torch vs onnxruntime parity of exported models that contain them."""
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_odom.profiles import PROFILES, GridProfile, get_profile  # noqa: E402
from radar_odom_export.cfar import CFARMask, odd_cells  # noqa: E402
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.normalise import order_statistic, rank_of_quantile  # noqa: E402

pytestmark = pytest.mark.torch


def tiny_profile(**kw):
    """W = 64 at 1 m/px, n = 4, yaw ±6° in 3° steps (a step that divides the turn, for the fast
    search), a 2-level U-Net, normalised input; a 9 m CFAR box, as the synthetic targets are
    blobs ~3 px wide (a box hardly wider than a target would count the target as its own
    background)."""
    base = dict(resolution_m=1.0, width_px=64, max_translation_m=4.0, rotation_range_rad=math.radians(6),
                rotation_step_rad=math.radians(3), unet_base_channels=4, unet_depth=2,
                input_norm="floor-scale", near_range_m=0.0, cfar_window_m=9.0)
    base.update(kw)
    return GridProfile("tiny-norm", **base)


def radius_map(width_px):
    c = (width_px - 1) / 2
    d = np.arange(width_px) - c
    return np.sqrt(d[:, None] ** 2 + d[None, :] ** 2)


def scene(width_px=64, seed=0, batch=2, floor=0.05):
    """float32[B, W, W] in [0, 1): a speckle floor with bright sparse reflectors (radar-like)."""
    rng = np.random.default_rng(seed)
    img = floor * rng.random((batch, width_px, width_px))
    for b in range(batch):
        idx = rng.integers(4, width_px - 4, size=(60, 2))
        img[b, idx[:, 0], idx[:, 1]] += rng.uniform(0.2, 0.6, size=60)
        img[b, idx[:30, 0], idx[:30, 1] + 1] += 0.3  # short extended targets
    return torch.from_numpy(img.astype(np.float32))


def pair_with_pose(pose, width_px=64, count=25, seed=0):
    """(prev, cur) float32[W, W] images of static Gaussian blobs at 1 m/px seen from frames
    related by ``pose`` (Oxford convention: a point q_cur is at R·q_cur + t in prev)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.3 * width_px, 0.3 * width_px, size=(count, 2))
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    rel = pts - np.array([x, y])
    cur_pts = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)
    cw = (width_px - 1) / 2
    xs = (cw - np.arange(width_px))[:, None]
    ys = (np.arange(width_px) - cw)[None, :]

    def render(points):
        img = sum(np.exp(-((xs - px) ** 2 + (ys - py) ** 2) / (2 * 1.2**2)) for px, py in points)
        return img.astype(np.float32)

    return render(pts), render(cur_pts)


def normaliser(profile=None):
    return MaskedCorrelator(profile or tiny_profile(), masking="raw").normaliser


# ------------------------------------------------------------------ order statistics
@pytest.mark.parametrize("q", [0.01, 0.3, 0.5, 0.99, 1.0])
def test_order_statistic_is_the_kth_value(q):
    x = torch.randn(3, 101, 7)
    k = rank_of_quantile(q, 101)
    torch.testing.assert_close(order_statistic(x, q, dim=1), torch.kthvalue(x, k, dim=1).values)


# ------------------------------------------------------------------ the normaliser's properties
@pytest.mark.parametrize("gain,offset", [(3.0, 0.0), (0.25, 0.1), (1.7, -0.02)])
def test_cartesian_normalisation_ignores_gain_and_offset(gain, offset):
    norm = normaliser()
    z = scene() * 0.5 + 0.05  # keeps a·z + b inside [0, 1]: nothing clips
    a, b = norm(z), norm(gain * z + offset)
    assert float(a.max()) > 0.5  # not trivially zero
    torch.testing.assert_close(b, a, atol=1e-4, rtol=1e-4)


def test_polar_normalisation_ignores_gain_and_offset():
    geom = {"num_azimuths": 40, "num_bins": 400, "range_resolution_m": 0.1, "range_offset_m": 0.0}
    model = MaskedCorrelator(tiny_profile(input_kind="polar", near_range_m=2.0), masking="raw",
                             sweep_geometry=geom)
    a_, b_ = model.to_cartesian.input_shape
    rng = np.random.default_rng(1)
    z = torch.from_numpy((0.05 + 0.5 * rng.random((2, a_, b_)) ** 6).astype(np.float32))
    ref = model.normalise(z)
    torch.testing.assert_close(model.normalise(2.5 * z + 0.1), ref, atol=1e-4, rtol=1e-4)
    # near-range bins do not set the scale: a blinding vehicle return changes nothing beyond it
    near = int(model.normaliser.keep.argmax())
    hot = z.clone()
    hot[:, :, :near] = 1.0
    torch.testing.assert_close(model.normalise(hot)[..., near:], ref[..., near:])


def test_a_range_dependent_floor_is_removed():
    """A smooth floor f(r) added to the sweep (another radar's noise floor in range) is taken
    out: the normalised sweep is the one without it, to interpolation accuracy."""
    norm = normaliser()
    z = scene(floor=0.03)
    f = torch.from_numpy((0.15 * np.exp(-radius_map(64) / 12.0) + 0.002 * radius_map(64)).astype(np.float32))
    # compared where the features live (the support disc): beyond it the floor is the last ring's
    disc = torch.from_numpy(radius_map(64) <= norm.radius_px)
    a, b = norm(z)[:, disc], norm(z + f)[:, disc]
    assert float((a - b).abs().max()) < 0.03  # normalised units: 1 is the 99th percentile
    # and without the normalisation the floor would have dominated the sweep
    assert float(f.mean()) > float(z.mean())


@pytest.mark.parametrize("value", [0.0, 0.3, 1.0])
def test_constant_and_blank_sweeps_give_zeros_never_nan(value):
    for norm in (normaliser(), normaliser(tiny_profile(norm_clip=0.0))):
        out = norm(torch.full((2, 64, 64), value))
        assert torch.isfinite(out).all() and float(out.abs().max()) == 0.0


def test_saturated_pixels_are_clipped():
    z = scene()
    z[:, 30:32, 30:34] = 50.0  # a few pixels far above everything else
    out = normaliser()(z)
    assert float(out.max()) == pytest.approx(4.0)
    assert float(normaliser(tiny_profile(norm_clip=0.0))(z).max()) > 4.0


def test_blank_sweep_gives_a_finite_pose():
    model = MaskedCorrelator(tiny_profile(), masking="raw").eval()
    with torch.no_grad():
        pose, cov = model(torch.zeros(1, 64, 64), torch.full((1, 64, 64), 0.2))
    assert torch.isfinite(pose).all() and torch.isfinite(cov).all()


def test_gradients_reach_the_masker_through_the_normalised_sweep():
    """Nothing is detached: the masker sees Z_n and the features are M(Z_n) ⊙ Z_n."""
    torch.manual_seed(0)
    model = MaskedCorrelator(tiny_profile(beta_pose=1.0))
    z = scene().requires_grad_(True)
    pose, _ = model(z[:1], z[1:])
    ((pose - torch.tensor([1.0, -1.0, 0.02])) ** 2).sum().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name
    assert torch.isfinite(z.grad).all() and z.grad.abs().sum() > 0  # through floor and scale too


def test_the_model_matches_the_same_pose_at_any_gain():
    """The point of it all: the pose does not depend on the radar's gain and offset."""
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose((2.0, -1.0, math.radians(3))))
    prev, cur = 0.05 + 0.1 * prev, 0.05 + 0.1 * cur  # a dim sweep on a floor
    model = MaskedCorrelator(tiny_profile(beta_pose=0.3), masking="raw").eval()
    raw = MaskedCorrelator(tiny_profile(beta_pose=0.3, input_norm="none"), masking="raw").eval()
    with torch.no_grad():
        dim, bright = model(prev, cur)[0], model(4 * prev, 4 * cur)[0]
        raw_dim, raw_bright = raw(prev, cur)[0], raw(4 * prev, 4 * cur)[0]
    torch.testing.assert_close(bright, dim, atol=1e-4, rtol=1e-4)
    np.testing.assert_allclose(dim[0].numpy(), [2.0, -1.0, math.radians(3)], atol=0.1)
    assert float((raw_bright - raw_dim).abs().max()) > 0.1  # unnormalised: the gain moves it


# ------------------------------------------------------------------ the profile field
def test_profile_field_defaults_to_none_and_travels_in_metadata():
    assert GridProfile("x", resolution_m=1.0, width_px=64).input_norm == "none"
    for name in ("cart-0.8", "cart-0.4", "cart-0.2", "polar-0.4", "dual-0.8"):
        assert PROFILES[name].input_norm == "floor-scale"
    p = get_profile("cart-0.4").with_(norm_floor_quantile=0.3, cfar_alpha=2.0)
    assert GridProfile.from_metadata(p.to_metadata()) == p
    # metadata written before the field existed (the shipped models) reads back as "none"
    import json

    old = json.loads(p.to_metadata()["radar_odom.profile"])
    for key in [k for k in old if k.startswith(("input_norm", "norm_", "cfar_"))]:
        del old[key]
    assert GridProfile.from_metadata({"radar_odom.profile": json.dumps(old)}).input_norm == "none"
    with pytest.raises(ValueError, match="input_norm"):
        GridProfile("x", resolution_m=1.0, width_px=64, input_norm="z-score")
    with pytest.raises(ValueError, match="quantile"):
        GridProfile("x", resolution_m=1.0, width_px=64, norm_scale_quantile=1.5)


def test_input_norm_none_leaves_the_sweep_alone():
    model = MaskedCorrelator(tiny_profile(input_norm="none"), masking="raw")
    z = scene()
    assert model.normaliser is None and model.normalise(z) is z


def test_named_profiles_build_with_normalisation():
    for name in ("cart-0.8", "polar-0.4", "dual-0.8"):
        model = MaskedCorrelator(get_profile(name), masking="raw")
        assert model.normaliser is not None


# ------------------------------------------------------------------ CFAR
def test_cfar_keeps_targets_standing_out_of_their_surroundings():
    cfar = CFARMask((5, 5), alpha=3.0, min_level=0.2)
    z = torch.zeros(1, 32, 32)
    z[0, 10, 10] = 1.0  # a point target on nothing: kept
    z[0, 20:30, 5:30] = 0.8  # a wide bright patch: its inside is not above 3× its mean
    z[0, 5, 25] = 0.1  # below the minimum level
    m = cfar(z)[0]
    assert float(m[10, 10]) > 0.99 and float(m[25, 17]) < 0.01 and float(m[5, 25]) < 0.01
    assert float(m[0, 0]) < 0.01  # nothing there
    assert odd_cells(4.0, 0.4) == 11 and odd_cells(4.0, 0.8) == 5 and odd_cells(0.1, 1.0) == 1
    with pytest.raises(ValueError, match="odd"):
        CFARMask((4, 5), 3.0, 0.2)


def test_cfar_mask_is_invariant_to_gain_and_offset():
    model = MaskedCorrelator(tiny_profile(), masking="cfar")
    z = scene() * 0.5 + 0.05
    m = model.mask(z)
    assert 0.001 < float(m.mean()) < 0.5  # keeps something, not everything
    for gain, offset in ((4.0, 0.0), (0.3, 0.2)):
        torch.testing.assert_close(model.mask(gain * z + offset), m, atol=1e-3, rtol=0)


def test_cfar_needs_the_normalised_input_and_has_no_weights():
    with pytest.raises(ValueError, match="floor-scale"):
        MaskedCorrelator(tiny_profile(input_norm="none"), masking="cfar")
    model = MaskedCorrelator(tiny_profile(), masking="cfar")
    assert model.state_dict() == {} and model.masker is None


@pytest.mark.parametrize("mode", ["single", "dual"])
def test_cfar_and_normalised_models_stream_like_the_pair_form(mode):
    torch.manual_seed(0)
    for masking in ("cfar", "learned"):
        model = MaskedCorrelator(tiny_profile(mode=mode, beta_pose=0.3), masking=masking).eval()
        seq = [scene(seed=s, batch=1) for s in range(3)]
        with torch.no_grad():
            state = model.initial_state(seq[0])
            for prev, cur in zip(seq, seq[1:]):
                pose_s, cov_s, state = model.stream_step(cur, state)
                pose_p, cov_p = model(prev, cur)
                torch.testing.assert_close(pose_s, pose_p, rtol=1e-5, atol=1e-5)


# ------------------------------------------------------------------ export
@pytest.fixture(scope="module")
def trained_cfar(tmp_path_factory):
    """`train(masking="cfar")` on a toy drive: the checkpoint a user without ground truth gets."""
    from radar_odom_export import data as D
    from radar_odom_export.train import TrainConfig, train

    folder = tmp_path_factory.mktemp("cfar")
    profile = tiny_profile(beta_pose=0.3)
    drives = [D.toy_drive(profile, 5, 1)]
    summary = train(TrainConfig(output=str(folder / "cfar.pt"), profile=profile, masking="cfar", batch=2,
                                threads=1), drives, drives)
    return folder / "cfar.pt", summary


def test_train_writes_a_weightless_cfar_checkpoint(trained_cfar):
    from radar_odom_export.checkpoint import load_checkpoint

    path, summary = trained_cfar
    model, meta = load_checkpoint(path)
    assert meta["masking"] == "cfar" and model.masking == "cfar" and model.cfar is not None
    assert meta["train"]["objective"] == "cfar" and summary["steps"] == 0
    assert math.isfinite(summary["best_val"])
    assert torch.load(path, weights_only=True)["state_dict"] == {}


@pytest.mark.slow
@pytest.mark.parametrize("search", ["exhaustive", "fast"])
def test_exported_cfar_model_matches_torch_in_onnxruntime(trained_cfar, tmp_path, capsys, search):
    """`radar-odom export` of the cfar checkpoint: the same one-graph interface, the
    normalisation and the mask inside, torch parity on a real-looking pair at two gains."""
    import onnx

    from radar_odom.commands.cli import main
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.fast_search import FastStreamStep

    path, _ = trained_cfar
    out = tmp_path / f"cfar-{search}.onnx"
    assert main(["export", str(path), "-o", str(out), "--search", search, "--no-calibrate"]) == 0
    assert "onnxruntime vs torch" in capsys.readouterr().out
    ops = {n.op_type for n in onnx.load(str(out)).graph.node}
    assert {"TopK", "AveragePool", "Sigmoid"} <= ops and not {"DFT", "STFT"} & ops
    ort_model = OnnxModel(out, threads=1)
    info = ort_model.info
    assert info.masking == "cfar" and info.profile.input_norm == "floor-scale"
    assert info.inputs == ("cart", "prev_state") and info.outputs == ("pose", "covariance", "state")
    model, _ = load_checkpoint(path)
    step = FastStreamStep(model) if search == "fast" else None
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose((2.0, -1.0, math.radians(3)), seed=3))
    prev, cur = 0.05 + 0.3 * prev, 0.05 + 0.3 * cur
    poses = []
    for gain in (1.0, 3.0):
        p, c = gain * prev, gain * cur
        with torch.no_grad():
            state = model.initial_state(p)
            want = step(c, state) if step is not None else model.stream_step(c, state)
        got = ort_model.run({"cart": c.numpy(), "prev_state": state.numpy()})
        np.testing.assert_allclose(got["pose"], want[0].numpy(), atol=1e-4)
        np.testing.assert_allclose(got["covariance"], want[1].numpy(), rtol=1e-3, atol=1e-6)
        poses.append(got["pose"][0])
    np.testing.assert_allclose(poses[1], poses[0], atol=1e-4)  # gain-invariant in the graph too
    np.testing.assert_allclose(poses[0], [2.0, -1.0, math.radians(3)], atol=0.2)


@pytest.mark.slow
@pytest.mark.parametrize("kind,mode,masking", [("cartesian", "single", "learned"), ("polar", "single", "cfar"),
                                               ("cartesian", "dual", "learned")])
def test_exported_normalised_models_match_torch(tmp_path, kind, mode, masking):
    """The exhaustive export of each normaliser / masking / mode: onnxruntime = torch."""
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.onnx_export import export_model

    torch.manual_seed(0)
    geom = {"num_azimuths": 120, "num_bins": 600, "range_resolution_m": 0.1, "range_offset_m": 0.0}
    model = MaskedCorrelator(tiny_profile(beta_pose=0.3, input_kind=kind, mode=mode, near_range_m=2.0),
                             masking=masking, sweep_geometry=geom).eval()
    report = export_model(model, tmp_path / "m.onnx", verify=True)  # verify: random sparse sweeps
    assert report.max_pose_diff < 1e-4 and "TopK" in report.ops
    if kind == "polar" or mode == "dual":
        return
    ort_model = OnnxModel(report.path, threads=1)
    z = scene(seed=5, batch=2)
    with torch.no_grad():
        state = model.initial_state(z[:1])
        want = model.stream_step(z[1:], state)
    got = ort_model.run({"cart": z[1:].numpy(), "prev_state": state.numpy()})
    np.testing.assert_allclose(got["pose"], want[0].numpy(), atol=1e-4)
    np.testing.assert_allclose(got["state"], want[2].numpy(), atol=1e-4 * float(want[2].abs().max()))


# ------------------------------------------------------------------ real sweeps
OXFORD_PAIR = "oxford-2019-01-10-14-36-48"  # two consecutive sweeps with ground truth


@pytest.mark.real
def test_real_oxford_pair_is_matched_at_any_gain(real_data_dir):
    """A real Navtech pair (0.865 m forward): the normalised cfar and raw models find the
    motion at the paper's β = 1, and multiplying the sweeps' power by 4 changes nothing (at
    β = 0.1 it moves the unnormalised raw model's soft-argmax from ≈ 0 to the motion)."""
    import radar_odom

    root = real_data_dir / OXFORD_PAIR
    if not root.is_dir():
        pytest.skip(f"{root} not found")
    seq = radar_odom.read_sequence(root)
    gt = seq.gt_relative[0]
    profile = get_profile("cart-0.8")
    assert profile.beta_pose == 1.0
    carts = [torch.from_numpy(radar_odom.polar_to_cartesian(seq.scan(i), profile.resolution_m, profile.width_px,
                                                            near_range_m=profile.near_range_m))[None]
             for i in range(2)]
    for masking in ("cfar", "raw"):
        model = MaskedCorrelator(profile, masking=masking).eval()
        with torch.no_grad():
            pose = model(*carts)[0][0].numpy()
            bright = model(*(4 * c for c in carts))[0][0].numpy()
        np.testing.assert_allclose(bright, pose, atol=1e-4)
        assert abs(pose[0] - gt[0]) < 0.2 and abs(pose[1] - gt[1]) < 0.2, (masking, pose, gt)
        assert abs(pose[2] - gt[2]) < math.radians(0.5), (masking, pose, gt)
