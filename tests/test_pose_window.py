"""The local pose window of the soft-argmax (`GridProfile.pose_window_cells`)."""
from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from test_fast_search import pair_with_pose, tiny_profile  # noqa: E402

from radar_odom_export.correlation import candidate_poses  # noqa: E402
from radar_odom_export.fast_search import FastSearchSettings, FastStreamStep  # noqa: E402
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.onnx_export import export_fast  # noqa: E402
from radar_odom_export.softargmax import peak_window, soft_argmax  # noqa: E402

pytestmark = pytest.mark.torch


def two_peak_volume(profile):
    """A volume with a strong peak at (+2, 0) cells, yaw 0 and a weaker one at (−2, 0)."""
    k, n = profile.num_rotations, profile.num_translations
    vol = torch.zeros(1, k, n, n)
    c = n // 2
    vol[0, k // 2, c + 2, c] = 5.0
    vol[0, k // 2, c - 2, c] = 4.0
    return vol


def test_global_soft_argmax_averages_the_modes_and_the_window_keeps_the_best():
    p = tiny_profile()
    cand = candidate_poses(p)
    vol = two_peak_volume(p)
    glob_pose, glob_cov = soft_argmax(vol, cand, beta=1.0)
    win_pose, win_cov = soft_argmax(vol, cand, beta=1.0, window=(1.0 + 1e-6, p.rotation_step_rad + 1e-6))
    # hand-computed: weights e^5 and e^4 at ±2 m, e^0 on every other candidate
    s = vol.numel()
    w = np.array([math.e**5, math.e**4, float(s - 2)])
    assert float(glob_pose[0, 0]) == pytest.approx((2 * w[0] - 2 * w[1]) / w.sum(), rel=1e-4)
    # the window (±1 cell, ±1 yaw step) around the best: the peak and 3·3·3 − 1 unit cells
    # and the window's 26 unit cells sit symmetrically about x = 2 m, so its mean is the peak
    assert float(win_pose[0, 0]) == pytest.approx(2.0, abs=1e-5)
    assert float(win_pose[0, 0]) > 1.9 > float(glob_pose[0, 0])
    torch.testing.assert_close(win_cov, glob_cov)  # the covariance still sees both modes


def test_peak_window_marks_the_cells_around_the_best_candidate():
    p = tiny_profile()
    cand = candidate_poses(p)
    vol = two_peak_volume(p)
    mask = peak_window(vol, cand[0, :, 0, 0], cand[0, 0, :, 1], cand[:, 0, 0, 2], 1.0 + 1e-6, 1e-6)
    c = p.num_translations // 2
    assert int(mask.sum()) == 9
    assert float(mask[0, p.num_rotations // 2, c + 2, c]) == 1.0
    assert float(mask[0, p.num_rotations // 2, c - 2, c]) == 0.0


def full_band_and_exhaustive(yaw_deg: float, **profile_fields):
    """(model, cur, state, exhaustive step output, full-band fast step output) for a raw model on
    a blob pair moved by (2.3 m, −1.4 m, yaw_deg)."""
    torch.manual_seed(0)
    p = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                     rotation_step_rad=math.radians(1), **profile_fields)
    model = MaskedCorrelator(p, masking="raw").eval()
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose((2.3, -1.4, math.radians(yaw_deg)), 64, 1.0, seed=3))
    full = FastStreamStep(model, FastSearchSettings(coarse_factor=2, band_half_width=6, rotation="bilinear"))
    with torch.no_grad():
        state = model.initial_state(prev)
        return model, cur, state, model.stream_step(cur, state), full(cur, state)


def test_fast_search_window_matches_the_exhaustive_window():
    _, _, _, want, got = full_band_and_exhaustive(2.0, pose_window_cells=2, beta_pose=0.05)
    torch.testing.assert_close(got[0], want[0], atol=1e-5, rtol=1e-5)
    assert abs(float(want[0][0, 0]) - 2.3) < 0.35 and abs(float(want[0][0, 1]) + 1.4) < 0.35


@pytest.mark.slow
def test_windowed_fast_export_matches_torch(tmp_path):
    from radar_odom.onnx_model import OnnxModel

    torch.manual_seed(1)
    p = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                     rotation_step_rad=math.radians(1), pose_window_cells=2, beta_pose=0.05)
    model = MaskedCorrelator(p, masking="learned").eval()
    settings = FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1)
    report = export_fast(model, tmp_path / "w.onnx", settings, verify=False)
    step = FastStreamStep(model, settings).eval()
    prev, cur = (torch.from_numpy(a)[None] for a in pair_with_pose((2.0, -1.0, math.radians(3)), 64, 1.0, seed=3))
    with torch.no_grad():
        state = model.initial_state(prev)
        want = step(cur, state)
    got = OnnxModel(report.path, threads=1).run({"cart": cur.numpy(), "prev_state": state.numpy()})
    np.testing.assert_allclose(got["pose"], want[0].numpy(), atol=1e-4)


# ------------------------------------------------------------------ parabolic sub-cell peak
def quadratic_volume(profile, centre_cells):
    """C = 10 − Σ (index − centre)² over (yaw, x, y) cells: a parabola peaked between cells."""
    k, n = profile.num_rotations, profile.num_translations
    kk, ii, jj = torch.meshgrid(torch.arange(k), torch.arange(n), torch.arange(n), indexing="ij")
    ck, ci, cj = centre_cells
    return (10.0 - (kk - ck) ** 2 - (ii - ci) ** 2 - (jj - cj) ** 2).float()[None]


def test_parabolic_peak_recovers_a_sub_cell_maximum_exactly():
    from radar_odom_export.softargmax import parabolic_peak

    p = tiny_profile()
    c = candidate_poses(p, dtype=torch.float64)
    n = p.num_translations // 2
    vol = quadratic_volume(p, (2.3, n + 1.4, n - 0.2)).double()
    pose = parabolic_peak(vol, c[0, :, 0, 0], c[0, 0, :, 1], c[:, 0, 0, 2], p.rotation_step_rad)[0]
    assert float(pose[0]) == pytest.approx(1.4 * p.resolution_m, abs=1e-6)
    assert float(pose[1]) == pytest.approx(-0.2 * p.resolution_m, abs=1e-6)
    assert float(pose[2]) == pytest.approx(0.3 * p.rotation_step_rad, abs=1e-6)
    # the soft-argmax at a high β snaps to the cell instead
    snapped, _ = soft_argmax(vol.float(), candidate_poses(p), beta=50.0)
    assert float(snapped[0, 0]) == pytest.approx(1.0 * p.resolution_m, abs=1e-4)


def test_parabolic_peak_on_the_border_or_without_curvature_stays_on_the_cell():
    from radar_odom_export.softargmax import parabolic_peak

    p = tiny_profile()
    c = candidate_poses(p)
    n = p.num_translations
    vol = quadratic_volume(p, (2.0, n - 1 + 0.4, 3.0))  # the best x cell is the last one
    pose = parabolic_peak(vol, c[0, :, 0, 0], c[0, 0, :, 1], c[:, 0, 0, 2], p.rotation_step_rad)[0]
    assert float(pose[0]) == pytest.approx(float(c[0, -1, 0, 0]))
    flat = torch.zeros(1, p.num_rotations, n, n)
    flat[0, 2, 3, 3] = 1.0  # neighbours equal on both sides: no sub-cell move
    pose = parabolic_peak(flat, c[0, :, 0, 0], c[0, 0, :, 1], c[:, 0, 0, 2], p.rotation_step_rad)[0]
    torch.testing.assert_close(pose, c[2, 3, 3])


@pytest.mark.slow
def test_parabolic_fast_search_matches_the_exhaustive_step_and_its_onnx_export(tmp_path):
    from radar_odom.onnx_model import OnnxModel

    model, cur, state, want, got = full_band_and_exhaustive(2.4, pose_estimator="parabolic")
    torch.testing.assert_close(got[0], want[0], atol=1e-5, rtol=1e-5)
    assert abs(float(want[0][0, 0]) - 2.3) < 0.2 and abs(float(want[0][0, 1]) + 1.4) < 0.2
    settings = FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1)
    report = export_fast(model, tmp_path / "p.onnx", settings, verify=False)
    step = FastStreamStep(model, settings).eval()
    with torch.no_grad():
        want = step(cur, state)
    got = OnnxModel(report.path, threads=1).run({"cart": cur.numpy(), "prev_state": state.numpy()})
    np.testing.assert_allclose(got["pose"], want[0].numpy(), atol=1e-4)
