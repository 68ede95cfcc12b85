"""The masker U-Net and the `MaskedCorrelator` model: shapes, streaming = pair, masking
options, gradients, and the polar input's mapping against the SDK's polar_to_cartesian."""
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_odom.polar import polar_to_cartesian_array  # noqa: E402
from radar_odom.profiles import GridProfile, get_profile  # noqa: E402
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.unet import UNet  # noqa: E402

pytestmark = pytest.mark.torch


def tiny_profile(**kw):
    """W = 32, n = 3, K = 5, a 2-level U-Net with 4 base channels: fast on CPU."""
    base = dict(resolution_m=1.0, width_px=32, max_translation_m=3.0,
                rotation_range_rad=math.radians(4), rotation_step_rad=math.radians(2),
                unet_base_channels=4, unet_depth=2)
    base.update(kw)
    return GridProfile("tiny", **base)


def sweeps(count, width=32, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return [torch.rand(2, width, width, generator=gen) for _ in range(count)]


# ------------------------------------------------------------------ U-Net
@pytest.mark.parametrize("channels", [1, 2])
def test_unet_shape_and_range(channels):
    net = UNet(channels, channels, base_channels=4, depth=3)
    out = net(torch.randn(2, channels, 64, 64) * 5)
    assert out.shape == (2, channels, 64, 64)
    assert out.min() >= 0 and out.max() <= 1 and out.std() > 0


def test_unet_pads_sizes_that_do_not_divide():
    """A 400-azimuth polar sweep is not a multiple of 2**5: padded inside, cropped back."""
    net = UNet(1, 1, base_channels=2, depth=5)
    assert net(torch.rand(1, 1, 400, 45)).shape == (1, 1, 400, 45)


def test_paper_unet_channels():
    net = UNet(1, 1)  # the paper's: 8 → 256 channels over 5 pools
    assert [blk[0].out_channels for blk in net.down] == [8, 16, 32, 64, 128, 256]
    assert [blk[2].out_channels for blk in net.up] == [8, 16, 32, 64, 128]
    assert net.head.out_channels == 1 and net.head.kernel_size == (1, 1)


# ------------------------------------------------------------------ model structure
def test_state_dict_holds_only_weights_and_profile_is_kept():
    profile = tiny_profile()
    learned = MaskedCorrelator(profile)
    assert learned.profile is profile
    assert all(k.startswith("masker.") for k in learned.state_dict())
    assert len(learned.state_dict()) == sum(1 for _ in learned.masker.parameters())
    assert MaskedCorrelator(profile, masking="raw").state_dict() == {}
    assert learned.candidates.shape == (5, 7, 7, 3)


def test_bad_options_are_rejected():
    with pytest.raises(ValueError, match="masking"):
        MaskedCorrelator(tiny_profile(), masking="oracle")
    with pytest.raises(ValueError, match="dft"):
        MaskedCorrelator(tiny_profile(), dft="dct")


# ------------------------------------------------------------------ streaming = pair
@pytest.mark.parametrize("dft", ["fft", "matmul"])
@pytest.mark.parametrize("mode", ["single", "dual"])
def test_stream_equals_pair(dft, mode):
    torch.manual_seed(0)
    model = MaskedCorrelator(tiny_profile(mode=mode, beta_pose=0.05, beta_cov=0.02), dft=dft)
    seq = sweeps(4)
    with torch.no_grad():
        state = model.initial_state(seq[0])
        for prev, cur in zip(seq, seq[1:]):
            pose_s, cov_s, state = model.stream_step(cur, state)
            pose_p, cov_p = model(prev, cur)
            torch.testing.assert_close(pose_s, pose_p, rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(cov_s, cov_p, rtol=1e-4, atol=1e-7)
    assert pose_s.shape == (2, 3) and cov_s.shape == (2, 3, 3)


def test_backends_give_the_same_model_output():
    torch.manual_seed(0)
    fft = MaskedCorrelator(tiny_profile(beta_pose=0.05, beta_cov=0.02), dft="fft")
    mm = MaskedCorrelator(tiny_profile(beta_pose=0.05, beta_cov=0.02), dft="matmul")
    mm.load_state_dict(fft.state_dict())
    prev, cur = sweeps(2)
    with torch.no_grad():
        for a, b in zip(fft(prev, cur), mm(prev, cur)):
            torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-5)


# ------------------------------------------------------------------ masking options
def test_raw_and_external_masks():
    profile = tiny_profile(beta_pose=0.05)
    prev, cur = sweeps(2)
    raw = MaskedCorrelator(profile, masking="raw")
    ext = MaskedCorrelator(profile, masking="external")
    ones = torch.ones_like(prev)
    torch.testing.assert_close(ext.correlation_volume(prev, cur, ones, ones),
                               raw.correlation_volume(prev, cur))
    # masking a sweep from outside is the same as matching the masked image raw
    half = (torch.arange(32) < 16).float().expand(2, 32, 32)
    torch.testing.assert_close(ext.correlation_volume(prev, cur, half, ones),
                               raw.correlation_volume(prev * half, cur))
    with pytest.raises(ValueError, match="prev_mask"):
        ext(prev, cur)
    with pytest.raises(ValueError, match="external"):
        raw(prev, cur, ones, ones)


@pytest.mark.parametrize("input_norm", ["none", "floor-scale"])
def test_raw_scan_model_is_finite_at_paper_beta(input_norm):
    """β = 1 on raw power (or on the normalised sweep, the named profile's default): C is in
    the hundreds, the soft-argmax must stay finite."""
    model = MaskedCorrelator(get_profile("cart-0.8").with_(input_norm=input_norm), masking="raw")
    gen = torch.Generator().manual_seed(0)
    prev = torch.rand(1, 128, 128, generator=gen) ** 4
    # moved 2 px ahead (+x = up) and 3 px right: the scene appears 2 px lower and 3 px left
    cur = torch.roll(prev, shifts=(2, -3), dims=(1, 2))
    with torch.no_grad():
        pose, cov = model(prev, cur)
    assert torch.isfinite(pose).all() and torch.isfinite(cov).all()
    np.testing.assert_allclose(pose[0].numpy(), [1.6, 2.4, 0.0], atol=1e-3)


@pytest.mark.parametrize("dft", ["fft", "matmul"])
def test_gradients_reach_every_masker_layer(dft):
    torch.manual_seed(0)
    model = MaskedCorrelator(tiny_profile(beta_pose=0.05), dft=dft)
    prev, cur = sweeps(2)
    pose, cov = model(prev, cur)
    ((pose - torch.tensor([1.0, -1.0, 0.02])) ** 2).sum().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


# ------------------------------------------------------------------ polar input
def polar_profile(**kw):
    return tiny_profile(resolution_m=0.8, width_px=64, input_kind="polar", max_translation_m=4.0,
                        **kw)


def test_polar_geometry_is_reduced_to_the_grid():
    model = MaskedCorrelator(polar_profile(), masking="raw")
    to_cart = model.to_cartesian
    # 0.8 m / 0.0432 m ≈ 18.5 → 19 bins averaged (0.8208 m); the corner of a 64-px 0.8 m
    # image is √2·25.2 m = 35.64 m away, bin u = (35.64 − 0.41)/0.8208 = 42.9, so bilinear
    # sampling reads bins 0..43
    assert to_cart.bin_factor == 19
    assert to_cart.input_shape == (400, 44)


# few azimuths (9° each) so that many pixels sample across the 0/2π seam; a Boreas-like
# range resolution and offset so that both enter the mapping
COARSE_SWEEP = {"num_azimuths": 40, "num_bins": 1000, "range_resolution_m": 0.0596,
                "range_offset_m": -0.31}


def test_polar_masked_features_match_polar_to_cartesian():
    """Features of a polar model = the SDK's polar_to_cartesian of (mask ⊙ reduced sweep),
    cut to the model's support disc."""
    profile = polar_profile()
    model = MaskedCorrelator(profile, masking="external", sweep_geometry=COARSE_SWEEP)
    f = model.to_cartesian.bin_factor
    assert f == 13  # round(0.8 / 0.0596)
    a, b = model.to_cartesian.input_shape
    rng = np.random.default_rng(0)
    sweep = rng.random((2, a, b)).astype(np.float32)
    mask = rng.random((2, a, b)).astype(np.float32)
    t = torch.from_numpy
    with torch.no_grad():
        s_prev, _ = model.features(t(sweep), t(sweep), t(mask), t(mask))
    azimuths = 2 * np.pi * np.arange(a) / a
    for k in range(2):
        want = polar_to_cartesian_array(mask[k] * sweep[k], azimuths, 0.0596 * f, -0.31,
                                        profile.resolution_m, profile.width_px,
                                        near_range_m=profile.near_range_m)
        want = want * model.support.numpy()
        np.testing.assert_allclose(s_prev[k].numpy(), want, atol=1e-4)


def test_polar_learned_model_runs_and_streams():
    torch.manual_seed(0)
    model = MaskedCorrelator(polar_profile(beta_pose=0.05))
    a, b = model.to_cartesian.input_shape
    seq = [torch.rand(1, a, b) for _ in range(2)]
    mask = model.mask(seq[0])
    assert mask.shape == (1, a, b) and 0 <= mask.min() and mask.max() <= 1
    with torch.no_grad():
        pose, cov, _ = model.stream_step(seq[1], model.initial_state(seq[0]))
        torch.testing.assert_close(pose, model(*seq)[0], rtol=1e-5, atol=1e-6)


def test_support_disc_makes_circular_correlation_linear():
    """With features cut to the support disc, the DFT volume equals the zero-padded (linear)
    correlation for every searched shift, even when the sweep fills the whole image."""
    from radar_odom.profiles import GridProfile
    profile = GridProfile("t", resolution_m=1.0, width_px=32, max_translation_m=4,
                          rotation_range_rad=0.02, rotation_step_rad=0.02, unet_base_channels=2,
                          unet_depth=2)
    model = MaskedCorrelator(profile, masking="raw")
    rng = np.random.default_rng(3)
    prev, cur = (torch.from_numpy(rng.random((1, 32, 32)).astype(np.float32)) for _ in range(2))
    with torch.no_grad():
        vol = model.correlation_volume(prev, cur)[0]
        s_prev, s_cur = model.features(prev, cur)
        rotated = model.rotator(s_cur)[0].numpy()
    n = profile.translation_cells
    a = s_prev[0].numpy()
    for k in range(rotated.shape[0]):
        padded = np.pad(rotated[k], n)
        for i in range(-n, n + 1):
            for j in range(-n, n + 1):
                # C[i, j] = Σ_q S_prev(q) rot(q − t): t = +i metres of x is −i rows
                shifted = padded[n + i: n + i + 32, n - j: n - j + 32]
                assert abs(float((a * shifted).sum()) - float(vol[k, i + n, j + n])) < 1e-3
    assert float(model.support.sum()) < 32 * 32 and float(model.support[16, 16]) == 1.0


def test_mask_downsample_runs_the_unet_on_the_pooled_image():
    from radar_odom.profiles import GridProfile
    p = GridProfile("t", resolution_m=1.0, width_px=64, max_translation_m=3,
                    rotation_range_rad=0.02, rotation_step_rad=0.02, unet_base_channels=2,
                    unet_depth=2, mask_downsample=4)
    model = MaskedCorrelator(p)
    seen = []
    model.masker.register_forward_hook(lambda mod, inp, out: seen.append(tuple(inp[0].shape)))
    with torch.no_grad():
        m = model.mask(torch.rand(2, 64, 64))
    assert seen == [(2, 1, 16, 16)] and m.shape == (2, 64, 64)
    assert float(m.min()) >= 0 and float(m.max()) <= 1


# ------------------------------------------------------------------ band limits of the features
def test_blur_images_is_a_normalised_gaussian_and_zero_sigma_is_no_kernel():
    from radar_odom_export.model import blur_images, gaussian_kernel_1d

    assert gaussian_kernel_1d(0.0).tolist() == [1.0]
    taps = gaussian_kernel_1d(2.0)
    assert taps.numel() == 13 and float(taps.sum()) == pytest.approx(1.0)
    img = torch.zeros(1, 41, 41)
    img[0, 20, 20] = 1.0
    out = blur_images(img, taps)[0]
    assert float(out.sum()) == pytest.approx(1.0, rel=1e-5)
    assert torch.allclose(out[20, 14:27], taps * taps[6], atol=1e-7)  # the row through the centre
    assert torch.allclose(out, out.T, atol=1e-7)


def _shift_match(profile, shift_px, sensor_blob: float):
    """(dx, dy) m read by a raw-masking model between a random scene and the same scene moved by
    ``shift_px`` (rows, cols), both with the same broad blob about the sensor added."""
    rng = np.random.default_rng(3)
    w = profile.width_px
    scene = np.zeros((w + 40, w + 40), np.float32)
    scene[rng.integers(0, w + 40, 120), rng.integers(0, w + 40, 120)] = 1.0
    yy, xx = np.mgrid[:w, :w] - (w - 1) / 2
    blob = sensor_blob * np.exp(-(xx ** 2 + yy ** 2) / (2 * (w / 6) ** 2)).astype(np.float32)
    a = scene[20:20 + w, 20:20 + w] + blob
    b = scene[20 + shift_px[0]:20 + shift_px[0] + w, 20 + shift_px[1]:20 + shift_px[1] + w] + blob
    model = MaskedCorrelator(profile, masking="raw").eval()
    with torch.no_grad():
        pose, _ = model(torch.from_numpy(a)[None], torch.from_numpy(b)[None])
    return pose[0, :2].numpy()


def test_the_highpass_keeps_a_sensor_centred_blob_from_pulling_the_match_to_zero():
    """Content fixed to the sensor matches itself at zero motion: with a broad blob about the sensor
    in both sweeps the match of a 3-pixel move reads short; the features' high-pass removes the blob
    and the move reads in full (GridProfile.feature_highpass_px)."""
    base = tiny_profile(width_px=64, resolution_m=1.0, max_translation_m=8.0, pose_estimator="parabolic",
                        rotation_range_rad=math.radians(1.0), rotation_step_rad=math.radians(0.5))
    plain = np.hypot(*_shift_match(base, (3, 0), sensor_blob=3.0))
    highpassed = np.hypot(*_shift_match(base.with_(feature_highpass_px=4.0), (3, 0), sensor_blob=3.0))
    assert plain < 2.0  # pulled toward 0 by the blob
    assert highpassed == pytest.approx(3.0, abs=0.3)
    # without the blob both read the move
    assert np.hypot(*_shift_match(base, (3, 0), sensor_blob=0.0)) == pytest.approx(3.0, abs=0.3)


def test_band_limit_fields_are_written_only_when_used():
    p = get_profile("cart-0.8")
    assert p.feature_highpass_px == 0.0 and p.feature_blur_px == 0.0
    text = p.to_metadata()["radar_odom.profile"]
    assert "feature_highpass_px" not in text and "feature_blur_px" not in text  # same digest as before them
    q = p.with_(feature_highpass_px=6.0, feature_blur_px=1.0)
    assert GridProfile.from_metadata(q.to_metadata()) == q
    assert GridProfile.from_metadata(p.to_metadata()) == p
    with pytest.raises(ValueError, match="feature_highpass_px"):
        p.with_(feature_highpass_px=1.0, feature_blur_px=2.0)  # a high-pass below the blur keeps nothing
    with pytest.raises(ValueError, match="feature_blur_px"):
        p.with_(feature_blur_px=-1.0)


def test_a_wide_lowpass_runs_pooled_and_matches_the_gaussian_it_stands_for():
    from radar_odom_export.model import blur_images, coarse_blur_factor, gaussian_kernel_1d, lowpass_images

    assert coarse_blur_factor(12.0, 256) == 4 and coarse_blur_factor(4.0, 256) == 1
    assert coarse_blur_factor(12.0, 66) == 1  # the pooling must divide the image
    gen = torch.Generator().manual_seed(0)
    img = torch.zeros(1, 128, 128)
    img[0, 20:108, 20:108] = torch.rand(88, 88, generator=gen)
    exact = blur_images(img, gaussian_kernel_1d(12.0))
    pooled = lowpass_images(img, 12.0)
    inner = (slice(None), slice(30, 98), slice(30, 98))
    assert float((pooled - exact)[inner].abs().max()) < 0.05 * float(exact[inner].max())
    # what the high-pass keeps (the image minus its low-pass) is the fine structure either way
    kept_exact, kept_pooled = img - exact, img - pooled
    assert float(torch.corrcoef(torch.stack([kept_exact[inner].flatten(), kept_pooled[inner].flatten()]))[0, 1]) > 0.99
