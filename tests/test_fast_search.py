"""The fast stream step: factored DFT and windowed inverse against torch.fft, polar rotation
against the rotation maths, equality with the exhaustive step when the band covers every yaw,
pose recovery on a synthetic pair with the coarse-to-fine search, and the ONNX export."""
import copy
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_odom.profiles import GridProfile, get_profile  # noqa: E402
from radar_odom_export.correlation import FFTCorrelation, PolarRotator, Rotator  # noqa: E402
from radar_odom_export.dft import FactoredSpectrum, LowResImage, WindowedInverse, dft_split  # noqa: E402
from radar_odom_export.fast_search import (  # noqa: E402
    FastSearchSettings,
    FastSequenceStep,
    FastStreamStep,
    default_settings,
)
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.onnx_export import export_fast  # noqa: E402

pytestmark = pytest.mark.torch


def tiny_profile(**kw):
    """W = 32, n = 3, yaw ±4° in 2° steps (K = 5), a 2-level U-Net: fast on CPU."""
    base = dict(resolution_m=1.0, width_px=32, max_translation_m=3.0, rotation_range_rad=math.radians(4),
                rotation_step_rad=math.radians(2), unet_base_channels=4, unet_depth=2)
    base.update(kw)
    return GridProfile("tiny", **base)


def blob_image(points_m, width_px, resolution_m, sigma_m=1.2):
    """float32[W, W]: Gaussian blobs at metric (x forward, y right) points, Cartesian convention."""
    c = (width_px - 1) / 2
    idx = np.arange(width_px)
    x = ((c - idx) * resolution_m)[:, None]
    y = ((idx - c) * resolution_m)[None, :]
    img = np.zeros((width_px, width_px))
    for px, py in points_m:
        img += np.exp(-((x - px) ** 2 + (y - py) ** 2) / (2 * sigma_m**2))
    return img.astype(np.float32)


def pair_with_pose(pose, width_px, resolution_m, count=25, radius_m=None, seed=0):
    """(prev, cur) images of static blobs seen from frames related by ``pose`` (Oxford: the
    current frame's pose in the previous one, so a point q_cur is at R·q_cur + t in prev)."""
    rng = np.random.default_rng(seed)
    radius_m = radius_m or 0.3 * width_px * resolution_m
    pts = rng.uniform(-radius_m, radius_m, size=(count, 2))
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    rel = pts - np.array([x, y])
    cur_pts = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)  # Rᵀ(q − t)
    return blob_image(pts, width_px, resolution_m), blob_image(cur_pts, width_px, resolution_m)


# ------------------------------------------------------------------ factored DFT
@pytest.mark.parametrize("width", [32, 48, 64, 128])
def test_factored_spectrum_is_rfft2_in_natural_order(width):
    fs = FactoredSpectrum(width).double()
    x = torch.rand(2, 3, width, width, dtype=torch.float64)
    nat = fs.to_natural(fs(x))
    ref = torch.fft.rfft2(x)
    scale = float(ref.abs().max())
    assert nat.shape == (2, 3, 2, width, width // 2 + 1)
    assert float((nat[..., 0, :, :] - ref.real).abs().max()) < 1e-6 * scale
    assert float((nat[..., 1, :, :] - ref.imag).abs().max()) < 1e-6 * scale
    assert torch.equal(fs.to_natural(fs.from_natural(nat)), nat)


def test_factorisation_splits_the_width():
    assert dft_split(512) == (16, 32) and dft_split(256) == (16, 16) and dft_split(128) == (8, 16)
    assert dft_split(48) == (4, 12) and dft_split(31) == (1, 31)  # a prime: one plain DFT


@pytest.mark.parametrize("width,n", [(32, 3), (64, 6)])
def test_windowed_inverse_equals_the_fft_correlation_volume(width, n):
    fs, wi, ref = FactoredSpectrum(width).double(), WindowedInverse(width, n).double(), FFTCorrelation(width, n)
    a = torch.rand(2, width, width, dtype=torch.float64)
    b = torch.rand(2, 4, width, width, dtype=torch.float64)
    got = wi(fs(a), fs(b))
    want = ref.correlate(ref.spectrum(a), ref.spectrum(b))
    assert got.shape == (2, 4, 2 * n + 1, 2 * n + 1)
    assert float((got - want).abs().max()) < 1e-6 * float(want.abs().max())


def test_low_res_inverse_recovers_the_image():
    x = torch.rand(3, 16, 16, dtype=torch.float64)
    spec = torch.fft.rfft2(x)
    assert torch.allclose(LowResImage(16).double()(torch.stack([spec.real, spec.imag], -3)), x, atol=1e-6)


# ------------------------------------------------------------------ polar rotation
def test_polar_rotation_moves_a_target_where_the_rotation_maths_says():
    """Rotation by yaw θ samples S(Rᵀ q) (correlation.rotation_grids): a target at p appears at
    R(θ)·p, i.e. the current sweep is drawn in the previous sweep's axes."""
    width, res = 96, 1.0
    point = np.array([20.0, 11.0])
    img = torch.from_numpy(blob_image([point], width, res))
    step = math.radians(0.5)
    rot = PolarRotator(width, step, radius_px=40, max_shift=30)
    shifts = torch.tensor([[-30, -7, 0, 12]])
    out = rot(img[None], shifts)[0].numpy()
    c = (width - 1) / 2
    idx = np.arange(width)
    xs, ys = ((c - idx) * res)[:, None], ((idx - c) * res)[None, :]
    for k, s in enumerate(shifts[0].tolist()):
        yaw = s * step
        want = np.array([math.cos(yaw) * point[0] - math.sin(yaw) * point[1],
                         math.sin(yaw) * point[0] + math.cos(yaw) * point[1]])
        w = out[k] * (out[k] > 0.2)
        got = np.array([(w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()])
        assert np.abs(got - want).max() < 0.15, (s, got, want)
    # fixed shifts (the coarse stage) take a folded path with the same result
    assert torch.allclose(rot.rotate_constant(img[None], shifts[0].tolist()), rot(img[None], shifts), atol=1e-5)


def test_polar_rotator_needs_a_step_that_divides_the_turn():
    with pytest.raises(ValueError, match="does not divide"):
        PolarRotator(32, 0.3, 10, 3)


# ------------------------------------------------------------------ the step
@pytest.mark.parametrize("masking", ["learned", "raw"])
def test_full_band_equals_the_exhaustive_stream_step(masking):
    torch.manual_seed(0)
    model = MaskedCorrelator(tiny_profile(), masking=masking).eval()
    prev, cur = torch.rand(2, 32, 32), torch.rand(2, 32, 32)
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=2, rotation="bilinear"))
    assert fast.exhaustive and fast.selector is None
    with torch.no_grad():
        state = model.initial_state(prev)
        want = model.stream_step(cur, state)
        got = fast(cur, state)
    assert torch.allclose(got[0], want[0], atol=1e-6)  # pose
    assert torch.allclose(got[1], want[1], rtol=1e-4, atol=1e-6)  # covariance
    assert torch.allclose(got[2], want[2], rtol=1e-5, atol=1e-4 * float(want[2].abs().max()))  # state


def test_states_are_interchangeable_with_the_exhaustive_step():
    """A stream may switch between the two steps: both keep the same state."""
    torch.manual_seed(1)
    model = MaskedCorrelator(tiny_profile(), masking="learned").eval()
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=1))
    sweeps = [torch.rand(1, 32, 32) for _ in range(3)]
    with torch.no_grad():
        state = model.initial_state(sweeps[0])
        _, _, s_fast = fast(sweeps[1], state)
        _, _, s_exh = model.stream_step(sweeps[1], state)
    assert torch.allclose(s_fast, s_exh, atol=1e-4 * float(s_exh.abs().max()))


@pytest.mark.parametrize("pose", [(3.0, -2.0, math.radians(4.0)), (-1.0, 4.0, math.radians(-3.0)),
                                  (2.0, 1.0, 0.0)])
def test_coarse_to_fine_recovers_a_known_pose(pose):
    """A synthetic pair related by a grid pose is matched with the band (3 of 13 yaws) picked
    by the coarse stage on 32 px images."""
    profile = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                           rotation_step_rad=math.radians(1), beta_pose=20.0, beta_cov=20.0, near_range_m=0.0)
    model = MaskedCorrelator(profile, masking="raw").eval()
    settings = FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1)
    fast = FastStreamStep(model, settings)
    assert not fast.exhaustive and fast.band == 3
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose(pose, 64, 1.0))
    with torch.no_grad():
        state = model.initial_state(prev)
        out_pose, cov, _ = fast(cur, state)
        exhaustive, _, _ = model.stream_step(cur, state)
    got = out_pose[0].numpy()
    assert abs(got[0] - pose[0]) < 0.3 and abs(got[1] - pose[1]) < 0.3
    assert abs(got[2] - pose[2]) < math.radians(0.6)
    assert np.allclose(got, exhaustive[0].numpy(), atol=0.2)  # the band holds the exhaustive peak
    assert torch.all(torch.linalg.eigvalsh(cov[0]) > -1e-6)


def test_band_moments_equal_the_candidate_list_formulas():
    """Mean and covariance from the weight grid's marginals = softargmax's over all candidates."""
    from radar_odom_export.fast_search import band_moments
    from radar_odom_export.softargmax import weighted_covariance, weighted_mean

    gen = torch.Generator().manual_seed(3)
    b, k, n = 2, 3, 5
    weights = torch.softmax(torch.randn(b, k * n * n, generator=gen, dtype=torch.float64) * 3, dim=1)
    offsets = torch.linspace(-2.0, 2.0, n, dtype=torch.float64)
    yaws = torch.tensor([[-0.02, -0.01, 0.0], [0.03, 0.04, 0.05]], dtype=torch.float64)
    mean, cov = band_moments(weights.reshape(b, k, n, n), offsets, yaws)
    for i in range(b):
        grid = torch.stack(torch.meshgrid(yaws[i], offsets, offsets, indexing="ij"), dim=-1)  # [K, N, N, (yaw x y)]
        cand = grid[..., [1, 2, 0]].reshape(-1, 3)
        w = weights[i : i + 1]
        assert torch.allclose(mean[i], weighted_mean(w, cand)[0], atol=1e-12)
        assert torch.allclose(cov[i], weighted_covariance(w, cand)[0], atol=1e-12)


def test_polar_rotation_keeps_yaw_zero_exact():
    """The yaw-0 slice is the features themselves (as in `Rotator`), not the blurred round trip."""
    model = MaskedCorrelator(tiny_profile(), masking="raw").eval()
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=1))
    blobs = [blob_image(np.random.default_rng(i).uniform(-8, 8, (6, 2)), 32, 1.0, sigma_m=2.0) for i in range(2)]
    feats = torch.from_numpy(np.stack(blobs)) * model.support  # smooth, zero beyond the disc
    indices = torch.tensor([[1, 2, 3], [0, 1, 2]])  # yaw 0 is index 2 (K = 5)
    rotated = fast.rotate(feats, indices)
    assert torch.equal(rotated[0, 1], feats[0]) and torch.equal(rotated[1, 2], feats[1])
    assert not torch.equal(fast.rotator(feats, indices - 2)[0, 1], feats[0])  # the round trip blurs
    bilinear = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=1, rotation="bilinear"))
    assert torch.allclose(rotated, bilinear.rotate(feats, indices), atol=0.1 * float(feats.max()))


# ------------------------------------------------------------------ resampled identity
def _rotation_pair(yaw_deg, width_px=128, count=60, sigma_m=1.5, seed=0):
    """(prev, cur) [1, W, W] of static blobs 20–50 px from the sensor, related by a pure
    rotation of ``yaw_deg`` (no translation): at 1° a blob moves 0.35–0.9 px."""
    rng = np.random.default_rng(seed)
    r, a = rng.uniform(20, 50, count), rng.uniform(0, 2 * np.pi, count)
    pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    cur = np.stack([c * pts[:, 0] + s * pts[:, 1], -s * pts[:, 0] + c * pts[:, 1]], axis=1)  # Rᵀ q
    return (torch.from_numpy(blob_image(p, width_px, 1.0, sigma_m))[None] for p in (pts, cur))


def _one_degree_profile(identity, width_px=128):
    return tiny_profile(width_px=width_px, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                        rotation_step_rad=math.radians(1), beta_pose=20.0, beta_cov=20.0, near_range_m=0.0,
                        pose_estimator="parabolic", rotation_identity=identity)


def test_a_one_step_rotation_is_not_read_as_straight():
    """The dead zone in yaw: with the exact identity yaw 0 is the image itself and every other
    yaw a blurred copy, so yaw 0 scores too high and a rotation of one yaw step reads as half
    of it; resampled like the others, yaw 0 has no advantage (fast search errors measured here:
    exact 0.43–0.53°, resampled ≤ 0.12° at ±1°)."""
    errors = {}
    for identity in ("exact", "resampled"):
        model = MaskedCorrelator(_one_degree_profile(identity), masking="raw").eval()
        fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=2))
        errs = []
        for seed in range(2):
            for yaw in (1.0, -1.0):
                prev, cur = _rotation_pair(yaw, seed=seed)
                with torch.no_grad():
                    pose = fast(cur, model.initial_state(prev))[0][0]
                    exhaustive = model.stream_step(cur, model.initial_state(prev))[0][0]
                # the fast and the exhaustive search (the training path) alike
                errs += [abs(math.degrees(p[2].item()) - yaw) for p in (pose, exhaustive)]
        errors[identity] = max(errs)
    assert errors["resampled"] < 0.2
    assert errors["exact"] > 0.35  # the setup sees the dead zone


def test_resampled_identity_rotates_every_yaw_through_the_polar_round_trip():
    profile = tiny_profile(rotation_identity="resampled")
    rot = Rotator(profile)
    assert not rot.exact_identity and Rotator(tiny_profile()).exact_identity
    images = torch.rand(2, 32, 32, generator=torch.Generator().manual_seed(0))
    out = rot(images)
    assert out.shape == (2, 5, 32, 32)
    want = rot.polar.rotate_constant(images, [-2, -1, 0, 1, 2])
    assert torch.equal(out, want)
    assert not torch.allclose(out[:, 2], images, atol=1e-3)  # yaw 0 is resampled too


def test_band_with_zero_appends_the_round_trip_at_shift_zero():
    rot = PolarRotator(32, math.radians(2), 12.0, 6)
    images = torch.rand(2, 32, 32, generator=torch.Generator().manual_seed(1))
    last = torch.tensor([-2, 5])
    plain = rot.rotate_band(images, last, 3)
    both = rot.rotate_band(images, last, 3, with_zero=True)
    assert both.shape == (2, 4, 32, 32)
    assert torch.equal(both[:, :3], plain)
    assert torch.allclose(both[:, 3], rot.rotate_constant(images, [0])[:, 0], atol=1e-6)


@pytest.mark.parametrize("masking", ["learned", "raw"])
def test_resampled_identity_full_band_equals_the_exhaustive_step(masking):
    """Fast (polar, every yaw in the band) and exhaustive (`Rotator`, resampled) compute the same
    volume; the state is the unrotated features' spectrum in both."""
    torch.manual_seed(0)
    model = MaskedCorrelator(tiny_profile(rotation_identity="resampled"), masking=masking).eval()
    prev, cur = torch.rand(2, 32, 32), torch.rand(2, 32, 32)
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=2))
    assert fast.exhaustive
    with torch.no_grad():
        state = model.initial_state(prev)
        want = model.stream_step(cur, state)
        got = fast(cur, state)
        pair = model(prev, cur)
        features = model.sweep_features(cur)
    torch.testing.assert_close(got[0], want[0], atol=1e-5, rtol=0)
    torch.testing.assert_close(got[1], want[1], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(want[2], model.correlation.spectrum(features), rtol=0, atol=0)
    torch.testing.assert_close(got[2], want[2], rtol=1e-5, atol=1e-4 * float(want[2].abs().max()))
    torch.testing.assert_close(pair[0], want[0], atol=1e-5, rtol=0)  # the pair form agrees


def test_a_resampled_identity_needs_the_polar_rotation():
    model = MaskedCorrelator(tiny_profile(rotation_identity="resampled"), masking="raw")
    with pytest.raises(ValueError, match="rotation='polar'"):
        FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=1, rotation="bilinear"))


def _rolled_reference(rot: PolarRotator, images, shifts):
    """The rotation as first written: a polar grid, K rolled and zero-padded copies, one
    bilinear table on them (the layout `PolarRotator` now avoids, for speed)."""
    import torch.nn.functional as F

    from radar_odom_export.correlation import bilinear_table, gather_lerp

    w, a, r, o = rot.width_px, rot.azimuths, rot.radii, rot.oversample
    c = (w - 1) / 2
    phi = torch.arange(a, dtype=torch.float32) * rot.bin_rad
    rho = torch.arange(r, dtype=torch.float32) * rot.radial_step_px
    index, fr, fc = bilinear_table(c - rho[None] * torch.cos(phi)[:, None],
                                   c + rho[None] * torch.sin(phi)[:, None], w, w)
    flat = F.pad(images, (1, 2, 1, 2)).reshape(images.shape[0], -1)
    polar = gather_lerp(flat, index.reshape(1, -1).expand(flat.shape[0], -1), fr.reshape(1, -1),
                        fc.reshape(1, -1), w + 3).reshape(-1, a, r)
    full = copy.copy(rot)
    full.crop = (0, w)  # every pixel sampled: the crop's zeros are checked, not assumed
    _, (az, rad) = full._tables(torch.float32)
    index, fr, fc = bilinear_table(az, rad, a + 1, r)
    out = []
    for b in range(images.shape[0]):
        for s in shifts[b].tolist():
            rolled = polar[b].roll(o * s, dims=0)  # row j: azimuth j − s (in polar rows)
            rolled = torch.cat([rolled, rolled[:1]])  # and the wrap-around row
            src = F.pad(rolled, (1, 2, 1, 2)).reshape(1, -1)
            out.append(gather_lerp(src, index.reshape(1, -1), fr.reshape(1, -1), fc.reshape(1, -1), r + 3))
    return torch.cat(out).reshape(*shifts.shape, w, w)


def test_polar_rotation_paths_equal_the_rolled_copies_exactly():
    """The wrapped padded grid read at row offsets (general shifts), as one block (a band of
    consecutive shifts) and with constant shifts gives the very floats of rolling copies."""
    gen = torch.Generator().manual_seed(3)
    rot = PolarRotator(32, math.radians(2), 12.0, 6)
    images = torch.rand(2, 32, 32, generator=gen)
    shifts = torch.tensor([[-6, -1, 0, 4, 6], [3, 4, 5, 6, -6]])
    ref = _rolled_reference(rot, images, shifts)
    assert torch.equal(rot(images, shifts), ref)
    band = torch.tensor([[-6, -5, -4], [4, 5, 6]])
    assert torch.equal(rot.rotate_band(images, band[:, -1], 3), _rolled_reference(rot, images, band))
    fixed = [-6, -2, 0, 2, 6]
    ref = _rolled_reference(rot, images, torch.tensor([fixed, fixed]))
    assert torch.allclose(rot.rotate_constant(images, fixed), ref, atol=1e-6)


def test_a_stray_coarse_pick_still_finds_the_straight_ahead_match():
    """Yaw 0 is always scored (from the new state's spectrum): a band far from the truth
    cannot hide a straight-ahead match."""
    profile = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                           rotation_step_rad=math.radians(1), beta_pose=20.0, beta_cov=20.0, near_range_m=0.0)
    model = MaskedCorrelator(profile, masking="raw").eval()
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=1))
    fast.selector.forward = lambda prev, cur: torch.full((prev.shape[0],), 11)  # yaw +5°: far off
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose((2.0, -1.0, 0.0), 64, 1.0))
    with torch.no_grad():
        pose, _, _ = fast(cur, model.initial_state(prev))
    assert np.allclose(pose[0].numpy(), [2.0, -1.0, 0.0], atol=0.05)


def test_batch_items_pick_their_own_bands():
    profile = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                           rotation_step_rad=math.radians(1), beta_pose=20.0, beta_cov=20.0, near_range_m=0.0)
    model = MaskedCorrelator(profile, masking="raw").eval()
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1))
    poses = [(3.0, -2.0, math.radians(4.0)), (-1.0, 4.0, math.radians(-3.0))]
    pairs = [pair_with_pose(p, 64, 1.0) for p in poses]
    prev = torch.from_numpy(np.stack([a for a, _ in pairs]))
    cur = torch.from_numpy(np.stack([b for _, b in pairs]))
    with torch.no_grad():
        state = model.initial_state(prev)
        batched = fast(cur, state)[0]
        single = torch.cat([fast(cur[i : i + 1], state[i : i + 1])[0] for i in range(2)])
    assert torch.allclose(batched, single, atol=1e-5)
    assert np.allclose(batched.numpy(), np.array(poses), atol=0.3)


@pytest.mark.parametrize("masking", ["learned", "raw"])
def test_sequence_step_equals_the_stream_step_pair_by_pair(masking):
    """T sweeps in one call give the T − 1 stream steps' poses and covariances (each sweep's own
    band, the state a stream would carry)."""
    torch.manual_seed(4)
    profile = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                           rotation_step_rad=math.radians(1), beta_pose=20.0, beta_cov=20.0, near_range_m=0.0)
    model = MaskedCorrelator(profile, masking=masking).eval()
    fast = FastStreamStep(model, FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1))
    rng = np.random.default_rng(5)
    # a drive of static blobs: each sweep from a frame moved by its own pose
    poses = [(rng.uniform(-3, 3), rng.uniform(-3, 3), math.radians(rng.uniform(-4, 4))) for _ in range(4)]
    sweeps = [pair_with_pose(p, 64, 1.0, seed=7) for p in [(0.0, 0.0, 0.0), *poses]]
    x = torch.from_numpy(np.stack([cur for _, cur in sweeps]))
    with torch.no_grad():
        pose, cov = FastSequenceStep(fast)(x)
        state = model.initial_state(x[:1])
        steps = []
        for k in range(1, len(x)):
            p, c, state = fast(x[k : k + 1], state)
            steps.append((p, c))
    assert pose.shape == (len(x) - 1, 3) and cov.shape == (len(x) - 1, 3, 3)
    torch.testing.assert_close(pose, torch.cat([p for p, _ in steps]), atol=1e-5, rtol=0)
    torch.testing.assert_close(cov, torch.cat([c for _, c in steps]), atol=1e-6, rtol=1e-4)


def test_bad_settings_and_models_are_refused():
    with pytest.raises(ValueError, match="rotation"):
        FastSearchSettings(rotation="nearest")
    with pytest.raises(ValueError, match=">= 1"):
        FastSearchSettings(coarse_factor=0)
    with pytest.raises(ValueError, match="does not divide"):
        FastStreamStep(MaskedCorrelator(tiny_profile(), masking="raw"),
                       FastSearchSettings(coarse_factor=3, band_half_width=0))
    with pytest.raises(ValueError, match="single-mode"):
        FastStreamStep(MaskedCorrelator(tiny_profile(mode="dual"), masking="raw"))


def test_default_settings_of_the_named_profiles_search_a_band():
    for name in ("cart-0.8", "cart-0.4", "cart-0.2"):
        p = get_profile(name)
        s = default_settings(p)
        assert 1 < s.band_size(p) < p.num_rotations
        assert p.width_px % s.coarse_factor == 0 and p.width_px // s.coarse_factor >= 64


# ------------------------------------------------------------------ export
@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(2)
    profile = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                           rotation_step_rad=math.radians(1))
    model = MaskedCorrelator(profile, masking="learned").eval()
    settings = FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1)
    path = tmp_path_factory.mktemp("fast") / "fast.onnx"
    return model, settings, export_fast(model, path, settings, verify=False)


@pytest.mark.slow
def test_export_has_no_dft_node_and_onnxruntime_matches_torch(exported):
    from radar_odom.onnx_model import OnnxModel

    model, settings, report = exported
    assert not {"DFT", "STFT"} & set(report.ops)
    assert "GridSample" not in report.ops  # the polar rotator gathers instead
    assert report.bytes < 2 * 2**20
    ort_model = OnnxModel(report.path, threads=1)
    assert ort_model.info.inputs == ("cart", "prev_state")
    meta = ort_model.session.get_modelmeta().custom_metadata_map
    assert '"band_rotations": 3' in meta["radar_odom.search"]
    step = FastStreamStep(model, settings).eval()
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose((2.0, -1.0, math.radians(3)), 64, 1.0, seed=3))
    with torch.no_grad():
        state = model.initial_state(prev)
        want = step(cur, state)
    got = ort_model.run({"cart": cur.numpy(), "prev_state": state.numpy()})
    np.testing.assert_allclose(got["pose"], want[0].numpy(), atol=1e-4)
    np.testing.assert_allclose(got["covariance"], want[1].numpy(), rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(got["state"], want[2].numpy(), rtol=1e-4, atol=1e-4 * float(want[2].abs().max()))



@pytest.mark.slow
@pytest.mark.parametrize("search", ["fast", "exhaustive"])
def test_a_resampled_identity_exports_and_onnxruntime_matches_torch(tmp_path, search):
    """Both searches of a `rotation_identity="resampled"` model export (verified against torch
    on fresh inputs inside the export) and carry the field in their metadata."""
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.onnx_export import export_model

    torch.manual_seed(3)
    profile = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                           rotation_step_rad=math.radians(1), rotation_identity="resampled")
    model = MaskedCorrelator(profile, masking="learned").eval()
    path = tmp_path / f"{search}.onnx"
    if search == "fast":
        report = export_fast(model, path, FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1))
    else:
        report = export_model(model, path)
    assert report.max_pose_diff is not None and report.max_pose_diff < 1e-3
    assert "GridSample" not in report.ops and not {"DFT", "STFT"} & set(report.ops)
    assert OnnxModel(path, threads=1).info.profile.rotation_identity == "resampled"


def test_the_rotation_samples_only_the_square_around_its_disc():
    """Pixels beyond the polar grid's reach read only its zero padding: the rotator samples the
    square around that disc and pads the rest, with the same result as sampling every pixel."""
    rot = PolarRotator(64, math.radians(2), 20.0, 6, oversample=1, radial_step_px=1.0, kernel="cubic")
    lo, size = rot.crop
    assert lo > 0 and size == 64 - 2 * lo  # 20 px radius in a 64 px image: a smaller square
    images = torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(5))
    shifts = torch.tensor([[-3, 0, 2], [1, 5, -6]])
    cropped = rot(images, shifts)
    full = copy.copy(rot)
    full.crop = (0, 64)
    assert torch.equal(cropped, full(images, shifts))
    outside = torch.ones(64, 64, dtype=torch.bool)
    outside[lo:lo + size, lo:lo + size] = False
    assert cropped[..., outside].abs().max() == 0
    assert full(images, shifts)[..., outside].abs().max() == 0  # the pixels left out were zeros anyway
