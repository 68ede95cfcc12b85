"""Correlation volume (FFT and matmul-DFT), rotation, candidates and soft-argmax.

References are written from the maths here: the score's definition summed directly, an
independent warp (cv2.remap on metric coordinates) for pose recovery, and hand-made volumes.
"""
import math

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_odom.profiles import GridProfile  # noqa: E402
from radar_odom_export.correlation import (  # noqa: E402
    FFTCorrelation,
    Rotator,
    candidate_poses,
    make_correlation,
    rotate_images,
    rotation_grids,
)
from radar_odom_export.dft import MatmulDFTCorrelation  # noqa: E402
from radar_odom_export.softargmax import hard_argmax, soft_argmax  # noqa: E402

pytestmark = pytest.mark.torch
BACKENDS = ("fft", "matmul")


def small_profile(width_px=16, n=2, k_half=1, res=1.0, step_deg=5.0, **kw):
    """A profile with K = 2·k_half + 1 rotations and N = 2n + 1 translations."""
    step = math.radians(step_deg)
    return GridProfile("test", resolution_m=res, width_px=width_px, max_translation_m=n * res,
                       rotation_range_rad=k_half * step, rotation_step_rad=step,
                       unet_depth=2, **kw)


def volume(backend: str, profile: GridProfile, prev: torch.Tensor, cur: torch.Tensor):
    corr = make_correlation(backend, profile.width_px, profile.translation_cells).to(prev.dtype)
    rot = Rotator(profile).to(prev.dtype)
    return corr.correlate(corr.spectrum(prev), corr.spectrum(rot(cur)))


# ------------------------------------------------------------------ the score's definition
@pytest.mark.parametrize("backend", BACKENDS)
def test_volume_equals_the_score_definition(backend):
    """C[k, i, j] = Σ_{r,c} S_prev[r, c]·Rot_k[(r + i) mod W, (c − j) mod W], summed directly."""
    w, n = 16, 3
    gen = torch.Generator().manual_seed(1)
    prev = torch.rand(2, w, w, dtype=torch.float64, generator=gen)
    rotated = torch.rand(2, 4, w, w, dtype=torch.float64, generator=gen)
    corr = make_correlation(backend, w, n).double()
    got = corr.correlate(corr.spectrum(prev), corr.spectrum(rotated)).numpy()
    p, rot = prev.numpy(), rotated.numpy()
    want = np.zeros((2, 4, 2 * n + 1, 2 * n + 1))
    for i in range(-n, n + 1):
        for j in range(-n, n + 1):
            shifted = np.roll(rot, shift=(-i, j), axis=(-2, -1))  # shifted[r, c] = rot[r+i, c−j]
            want[:, :, i + n, j + n] = (p[:, None] * shifted).sum(axis=(-2, -1))
    # the matmul constants are stored in float32: relative 1e-6 of the volume's scale
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())


@pytest.mark.parametrize("width", [64, 128])
def test_fft_and_matmul_volumes_agree(width):
    profile = small_profile(width_px=width, n=width // 8, k_half=2, res=0.5, step_deg=3.0)
    gen = torch.Generator().manual_seed(width)
    prev = torch.rand(2, width, width, generator=gen)
    cur = torch.rand(2, width, width, generator=gen)
    c_fft = volume("fft", profile, prev, cur)
    c_mm = volume("matmul", profile, prev, cur)
    assert c_fft.shape == (2, 5, profile.num_translations, profile.num_translations)
    err = (c_fft - c_mm).abs().max() / c_fft.abs().max()
    assert err <= 1e-4, f"relative difference {err:.2e}"


def test_both_backends_share_the_state_format():
    """Spectra are interchangeable: [..., 2, W, W//2 + 1], channel 0 real, 1 imaginary."""
    w = 32
    images = torch.rand(3, w, w, dtype=torch.float64)
    fft_spec = FFTCorrelation(w, 2).spectrum(images)
    mm_spec = MatmulDFTCorrelation(w, 2).double().spectrum(images)
    ref = np.fft.rfft2(images.numpy())
    assert fft_spec.shape == mm_spec.shape == (3, 2, w, w // 2 + 1)
    np.testing.assert_allclose(fft_spec[:, 0].numpy() + 1j * fft_spec[:, 1].numpy(), ref,
                               atol=1e-9)
    np.testing.assert_allclose(mm_spec.numpy(), fft_spec.numpy(), atol=1e-4)


def test_odd_width_windowed_inverse_matches_fft():
    """Odd W has no Nyquist column: the Hermitian weights must still give the exact inverse."""
    w, n = 21, 4
    prev, rot = torch.rand(1, w, w, dtype=torch.float64), torch.rand(1, 2, w, w,
                                                                     dtype=torch.float64)
    vols = []
    for cls in (FFTCorrelation, MatmulDFTCorrelation):
        corr = cls(w, n).double()
        vols.append(corr.correlate(corr.spectrum(prev), corr.spectrum(rot)))
    np.testing.assert_allclose(vols[1].numpy(), vols[0].numpy(), atol=1e-6 * vols[0].max().item())


def test_matmul_backend_uses_no_fft_and_no_complex(monkeypatch):
    def forbidden(*a, **k):
        raise AssertionError("torch.fft used in the matmul path")

    for name in ("rfft2", "irfft2", "fft2", "ifft2", "rfft", "irfft", "fft", "ifft"):
        monkeypatch.setattr(torch.fft, name, forbidden)
    corr = MatmulDFTCorrelation(32, 3)
    spec = corr.spectrum(torch.rand(1, 32, 32))
    vol = corr.correlate(spec, corr.spectrum(torch.rand(1, 2, 32, 32)))
    assert not spec.is_complex() and not vol.is_complex()
    assert all(not b.is_complex() and b.dtype == torch.float32 for b in corr.buffers())


def test_unknown_backend_is_rejected():
    with pytest.raises(ValueError, match="fft"):
        make_correlation("dct", 16, 2)


# ------------------------------------------------------------------ rotation and candidates
def test_quarter_turn_rotation_is_a_pixel_permutation():
    """yaw = +90°: Rot(p) = S(Rᵀp) = S(y, −x), i.e. Rot[r, c] = S[W−1−c, r] in pixels."""
    w = 17
    image = torch.rand(1, 1, w, w, dtype=torch.float64)
    grid = rotation_grids(torch.tensor([math.pi / 2], dtype=torch.float64), w)
    rot = torch.nn.functional.grid_sample(image, grid, align_corners=True)[0, 0].numpy()
    src = image[0, 0].numpy()
    want = np.array([[src[w - 1 - c, r] for c in range(w)] for r in range(w)])
    np.testing.assert_allclose(rot, want, atol=1e-9)


def test_rotator_keeps_yaw_zero_exact_and_order():
    profile = small_profile(width_px=32, k_half=2)
    images = torch.rand(2, 32, 32)
    out = Rotator(profile)(images)
    assert out.shape == (2, 5, 32, 32)
    assert torch.equal(out[:, 2], images)  # yaw 0 is the image itself, bit for bit
    # slices follow profile.rotations_rad: slice 0 is the most negative yaw
    grid = rotation_grids(torch.tensor(profile.rotations_rad[:1]), 32)
    first = torch.nn.functional.grid_sample(images[:, None], grid.expand(2, -1, -1, -1),
                                            align_corners=True)[:, 0]
    torch.testing.assert_close(out[:, 0], first)


def test_per_image_grids_rotate_each_image_by_its_own_yaws():
    """`rotate_images` with [B, K, W, W, 2] grids (the fast search's per-item yaw bands) gives,
    for each image, what the shared [K, W, W, 2] grids give: one rotation, two layouts."""
    images = torch.rand(3, 24, 24)
    yaws = torch.tensor([[-0.1, 0.0, 0.2], [0.05, 0.1, 0.3], [-0.3, -0.2, 0.0]])
    per_item = rotate_images(images, torch.stack([rotation_grids(y, 24) for y in yaws]))
    assert per_item.shape == (3, 3, 24, 24)
    for b in range(3):
        shared = rotate_images(images[b:b + 1], rotation_grids(yaws[b], 24))
        torch.testing.assert_close(per_item[b], shared[0], rtol=0, atol=1e-6)


def test_candidate_layout():
    profile = small_profile(n=2, k_half=1, res=0.4, step_deg=0.5)
    cand = candidate_poses(profile, dtype=torch.float64)
    assert cand.shape == (3, 5, 5, 3)
    k, i, j = 2, 4, 1  # yaw +0.5°, tx = +2 cells, ty = −1 cell
    np.testing.assert_allclose(cand[k, i, j].numpy(), [0.8, -0.4, math.radians(0.5)], atol=1e-12)


# ------------------------------------------------------------------ pose recovery
def synthetic_scene(width: int, margin_px: int, seed: int) -> np.ndarray:
    """float32[W, W]: smooth blobs and lines, zero beyond a disc (so no content wraps)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((width, width), np.float32)
    radius = width / 2 - margin_px
    c = (width - 1) / 2
    for _ in range(40):
        a, r = rng.uniform(0, 2 * np.pi), radius * np.sqrt(rng.uniform(0.02, 1))
        x, y = int(c + r * np.cos(a)), int(c + r * np.sin(a))
        cv2.circle(img, (x, y), 1, float(rng.uniform(0.5, 1.0)), -1)
    for _ in range(8):
        p = (c + rng.uniform(-0.6, 0.6, 2) * radius).astype(int)
        q = (c + rng.uniform(-0.6, 0.6, 2) * radius).astype(int)
        cv2.line(img, tuple(map(int, p)), tuple(map(int, q)), float(rng.uniform(0.3, 0.8)), 1)
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    rr, cc = np.mgrid[:width, :width]
    img[np.hypot(rr - c, cc - c) > radius] = 0.0
    return img


def warp_into_later_frame(prev: np.ndarray, pose_xyyaw, res: float) -> np.ndarray:
    """The later sweep's image: a static point q' of the later frame is at R q' + t earlier.

    S_cur(q') = S_prev(R(yaw) q' + t), sampled with cv2.remap on metric pixel coordinates
    (x = (cW − r)·res, y = (c − cW)·res) — independent of the model's grid_sample path.
    """
    w = prev.shape[0]
    c_w = (w - 1) / 2
    x_t, y_t, yaw = pose_xyyaw
    rows, cols = np.mgrid[:w, :w].astype(np.float64)
    x, y = (c_w - rows) * res, (cols - c_w) * res
    qx = np.cos(yaw) * x - np.sin(yaw) * y + x_t
    qy = np.sin(yaw) * x + np.cos(yaw) * y + y_t
    map_r, map_c = c_w - qx / res, c_w + qy / res
    return cv2.remap(prev, map_c.astype(np.float32), map_r.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)


RECOVERY_POSES = [  # (tx px, ty px, yaw deg): both signs, tx ≠ ty, off-grid values
    (3.3, -5.6, 2.1),
    (-4.7, 2.2, -3.4),
    (6.2, 1.4, 0.0),
]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("tx_px,ty_px,yaw_deg", RECOVERY_POSES)
def test_known_pose_is_recovered(backend, tx_px, ty_px, yaw_deg):
    res, step_deg = 0.5, 0.5
    profile = small_profile(width_px=128, n=10, k_half=10, res=res, step_deg=step_deg)
    prev = synthetic_scene(128, margin_px=16, seed=int(10 * tx_px) % 97)
    truth = np.array([tx_px * res, ty_px * res, math.radians(yaw_deg)])
    cur = warp_into_later_frame(prev, truth, res)
    vol = volume(backend, profile, torch.from_numpy(prev)[None], torch.from_numpy(cur)[None])
    cand = candidate_poses(profile)
    tol = np.array([0.5 * res, 0.5 * res, 0.5 * math.radians(step_deg)])
    best = hard_argmax(vol, cand)[0].numpy()
    assert np.all(np.abs(best - truth) <= tol), (best, truth)
    # a temperature that spreads weight over the peak's neighbours interpolates between
    # cells: within a quarter cell here (measured ≈ 0.1 px and 0.13 yaw steps at worst)
    beta = 40.0 / vol.max().item()
    mean, cov = soft_argmax(vol, cand, beta)
    err = np.abs(mean[0].numpy() - truth)
    assert np.all(err <= tol / 2), (mean, truth)
    assert np.all(np.linalg.eigvalsh(cov[0].double().numpy()) >= -1e-9)


# ------------------------------------------------------------------ gradients
@pytest.mark.parametrize("backend", BACKENDS)
def test_gradcheck_through_rotation_correlation_and_soft_argmax(backend):
    profile = small_profile(width_px=16, n=2, k_half=1, step_deg=7.0)
    corr = make_correlation(backend, 16, 2).double()
    rot = Rotator(profile).double()
    cand = candidate_poses(profile, dtype=torch.float64)
    gen = torch.Generator().manual_seed(3)
    prev = torch.rand(1, 16, 16, dtype=torch.float64, generator=gen, requires_grad=True)
    cur = torch.rand(1, 16, 16, dtype=torch.float64, generator=gen, requires_grad=True)

    def pose_and_cov(p, c):
        vol = corr.correlate(corr.spectrum(p), corr.spectrum(rot(c)))
        mean, cov = soft_argmax(vol, cand, beta=0.05, beta_cov=0.02)
        return mean, cov

    assert torch.autograd.gradcheck(pose_and_cov, (prev, cur), eps=1e-6, atol=1e-5)


# ------------------------------------------------------------------ soft-argmax by hand
def hand_candidates():
    """K = 3 (yaw −0.1, 0, 0.1 rad), N = 3 (−1, 0, 1 m)."""
    return candidate_poses(small_profile(n=1, k_half=1, step_deg=math.degrees(0.1)),
                           dtype=torch.float64)


def test_two_equal_peaks_give_the_midpoint_and_their_spread():
    cand = hand_candidates()
    vol = torch.zeros(1, 3, 3, 3, dtype=torch.float64)
    vol[0, 1, 0, 0] = vol[0, 2, 2, 2] = 100.0  # (−1, −1, 0) and (1, 1, 0.1)
    mean, cov = soft_argmax(vol, cand, beta=1.0)
    np.testing.assert_allclose(mean[0].numpy(), [0.0, 0.0, 0.05], atol=1e-12)
    # two points ±(1, 1, 0.05) about the mean with weight ½ each
    want = np.outer([1, 1, 0.05], [1, 1, 0.05])
    np.testing.assert_allclose(cov[0].numpy(), want, atol=1e-12)


def test_flat_volume_gives_the_grid_moments_and_beta_cov_is_separate():
    cand = hand_candidates()
    vol = torch.zeros(1, 3, 3, 3, dtype=torch.float64)
    vol[0, 1, 2, 0] = 50.0  # a sharp peak at (1, −1, 0)
    mean, cov = soft_argmax(vol, cand, beta=1.0, beta_cov=0.0)
    np.testing.assert_allclose(mean[0].numpy(), [1.0, -1.0, 0.0], atol=1e-12)
    # β_cov = 0: uniform weights over {−1, 0, 1}³·(1, 1, 0.1): variances 2/3, no correlation
    np.testing.assert_allclose(cov[0].numpy(), np.diag([2 / 3, 2 / 3, 0.01 * 2 / 3]),
                               atol=1e-12)


def test_huge_correlation_values_stay_finite():
    """Raw scans give C in the thousands; β·C must not overflow (hard argmax in the limit)."""
    cand = hand_candidates().float()
    vol = torch.full((1, 3, 3, 3), 5e5)
    vol[0, 0, 1, 2] = 6e5
    mean, cov = soft_argmax(vol, cand, beta=1.0)
    assert torch.isfinite(mean).all() and torch.isfinite(cov).all()
    np.testing.assert_allclose(mean[0].numpy(), [0.0, 1.0, -0.1], atol=1e-6)
    np.testing.assert_allclose(cov[0].numpy(), 0.0, atol=1e-9)


def test_covariance_floor_is_the_cell_quantisation_variance_on_a_one_cell_volume():
    from radar_odom_export.model import MaskedCorrelator

    p = GridProfile("floor", resolution_m=0.5, width_px=32, max_translation_m=1.5, rotation_range_rad=0.02,
                    rotation_step_rad=0.01, beta_pose=1.0, beta_cov=1.0, unet_depth=2)
    model = MaskedCorrelator(p, masking="raw")
    vol = torch.zeros(1, p.num_rotations, p.num_translations, p.num_translations)
    vol[0, 1, 3, 4] = 1e4  # every weight on one cell: eq. 3 alone gives Σ = 0
    pose, cov = model.pose_from_volume(vol)
    torch.testing.assert_close(pose[0], torch.tensor([0.0, 0.5, -0.01]))  # yaws -0.02..0.02
    expected = torch.diag(torch.tensor([0.25 / 12, 0.25 / 12, 1e-4 / 12]))
    torch.testing.assert_close(cov[0], expected)
    _, cov0 = MaskedCorrelator(p.with_(cov_floor_cells=0.0, cov_floor_yaw_cells=0.0),
                               masking="raw").pose_from_volume(vol)
    assert torch.count_nonzero(cov0) == 0
    # translation and yaw floors apart (in their own cells); the scale multiplies the moment only
    _, cov1 = MaskedCorrelator(p.with_(cov_floor_cells=0.2, cov_floor_yaw_cells=0.5, cov_scale=7.0),
                               masking="raw").pose_from_volume(vol)
    torch.testing.assert_close(cov1[0], torch.diag(torch.tensor([0.01 / 12, 0.01 / 12, 0.25e-4 / 12])))
    vol2 = vol.clone()
    vol2[0, 1, 3, 5] = 1e4  # two cells 0.5 m apart in y: moment 0.0625 m² on y
    _, a = MaskedCorrelator(p.with_(cov_floor_cells=0.0, cov_floor_yaw_cells=0.0), masking="raw").pose_from_volume(vol2)
    _, b = MaskedCorrelator(p.with_(cov_floor_cells=0.0, cov_floor_yaw_cells=0.0, cov_scale=7.0),
                            masking="raw").pose_from_volume(vol2)
    torch.testing.assert_close(a[0, 1, 1], torch.tensor(0.0625))
    torch.testing.assert_close(b, 7.0 * a)
