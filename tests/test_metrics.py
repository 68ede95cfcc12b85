"""KITTI odometry metric, per-step errors and Mahalanobis calibration: hand-computed cases."""
import math

import numpy as np
import pytest

from radar_odom.evaluation import metrics as M
from radar_odom.se2 import chain_relative, se2

# Frames 1 + 1e-9 m apart: a segment of L frames covers L·(1 + 1e-9) m > L, so it ends exactly
# L frames after its start and its chord is L m to 1e-9 (KITTI divides by the nominal L).
STEP_M = 1.0 + 1e-9


def straight(n_frames, step_m=STEP_M, yaw_per_step=0.0, scale=1.0):
    rel = np.tile([step_m * scale, 0.0, yaw_per_step], (n_frames - 1, 1))
    return chain_relative(rel)


def expected_count(n_frames, length_frames, step):
    """Start frames f = 0, step, 2·step, … whose end frame f + L exists."""
    return len(range(0, n_frames - length_frames, step))


def test_perfect_estimate_gives_zero():
    rng = np.random.default_rng(0)
    rel = np.column_stack([rng.uniform(1, 3, 600), rng.normal(0, 0.1, 600), rng.normal(0, 0.03, 600)])
    gt = chain_relative(rel)
    m = M.kitti_metrics(gt, gt.copy())
    assert m["translation_percent"] == pytest.approx(0, abs=1e-9)
    assert m["rotation_deg_per_m"] == pytest.approx(0, abs=1e-9)
    assert m["num_segments"] > 0 and m["step"] == 4 and m["pooling"] == "segments"


def test_two_percent_scale_error_gives_two_percent_and_no_rotation_error():
    gt = straight(1000)
    est = straight(1000, scale=1.02)
    m = M.kitti_metrics(gt, est)
    assert m["translation_percent"] == pytest.approx(2.0, rel=1e-8)
    assert m["rotation_deg_per_m"] == pytest.approx(0.0, abs=1e-12)
    assert [r["length_m"] for r in m["per_length"]] == [100, 200, 300, 400, 500, 600, 700, 800]
    for row in m["per_length"]:
        assert row["translation_percent"] == pytest.approx(2.0, rel=1e-8)


def test_segment_ends_at_first_frame_beyond_the_length_and_divides_by_nominal_length():
    # frames exactly 1 m apart: frame f+100 is at exactly +100 m (not beyond), so the segment ends
    # at f+101 and a 2 % scale error reads 2 % · 101 / 100 = 2.02 %
    m = M.kitti_metrics(straight(300, step_m=1.0), straight(300, step_m=1.0, scale=1.02), lengths=(100,))
    assert m["translation_percent"] == pytest.approx(2.02, rel=1e-9)
    assert m["num_segments"] == expected_count(300, 101, 4)


def test_scale_error_on_a_curvy_drive_gives_no_rotation_error():
    rng = np.random.default_rng(1)
    rel = np.column_stack([rng.uniform(1, 3, 500), rng.normal(0, 0.2, 500), rng.normal(0, 0.05, 500)])
    est_rel = rel.copy()
    est_rel[:, :2] *= 1.05
    m = M.kitti_metrics(chain_relative(rel), chain_relative(est_rel))
    assert m["rotation_deg_per_m"] == pytest.approx(0.0, abs=1e-10)
    assert 0 < m["translation_percent"] <= 5.0 + 1e-9  # chord ≤ path: at most 5 %


def test_constant_yaw_bias_gives_its_closed_form():
    # straight ground truth 1 m per frame; the estimate turns by δ every frame. Over a segment of
    # n frames the estimate turns nδ and its chord is Σ_k e^{ikδ} = e^{i(n−1)δ/2} sin(nδ/2)/sin(δ/2)
    # (complex plane, metres), against (n, 0) for the truth. So t_err = |n − that| / L, r_err = nδ/L.
    delta, n_frames, step = 1e-3, 1000, 4
    m = M.kitti_metrics(straight(n_frames), straight(n_frames, yaw_per_step=delta), step=step)
    t_expected, weights = [], []
    for row in m["per_length"]:
        n = int(row["length_m"])
        chord = STEP_M * np.exp(1j * (n - 1) * delta / 2) * math.sin(n * delta / 2) / math.sin(delta / 2)
        t_percent = 100 * abs(STEP_M * n - chord) / n
        assert row["translation_percent"] == pytest.approx(t_percent, rel=1e-6)
        assert row["rotation_deg_per_m"] == pytest.approx(math.degrees(n * delta) / n, rel=1e-9)
        assert row["num_segments"] == expected_count(n_frames, n, step)
        t_expected.append(t_percent)
        weights.append(row["num_segments"])
    assert m["translation_percent"] == pytest.approx(np.average(t_expected, weights=weights), rel=1e-6)
    assert m["rotation_deg_per_m"] == pytest.approx(math.degrees(delta), rel=1e-9)
    # sanity of the closed form itself: for small δ the lateral drift is ≈ nδ·n/2, so t ≈ 100·nδ/2 %
    assert m["per_length"][0]["translation_percent"] == pytest.approx(100 * 100 * delta / 2, rel=0.02)


@pytest.mark.parametrize("step", [1, 4, 10])
def test_step_sets_the_number_of_segments(step):
    n_frames = 450
    m = M.kitti_metrics(straight(n_frames), straight(n_frames, scale=1.01), step=step)
    counts = {int(r["length_m"]): r["num_segments"] for r in m["per_length"]}
    assert counts == {L: expected_count(n_frames, L, step) for L in (100, 200, 300, 400)}
    assert m["num_segments"] == sum(counts.values()) and m["step"] == step


def test_pooling_over_segments_weights_by_count_and_over_sequences_averages_sequences():
    seqs_gt = [straight(300), straight(900)]
    seqs_est = [straight(300, scale=1.02), straight(900, scale=1.04)]
    lengths = (100, 200)
    n_a = sum(expected_count(300, L, 4) for L in lengths)
    n_b = sum(expected_count(900, L, 4) for L in lengths)
    seg = M.kitti_metrics(seqs_gt, seqs_est, lengths=lengths, pooling="segments")
    seq = M.kitti_metrics(seqs_gt, seqs_est, lengths=lengths, pooling="sequences")
    assert seg["num_segments"] == seq["num_segments"] == n_a + n_b
    assert seg["translation_percent"] == pytest.approx((2 * n_a + 4 * n_b) / (n_a + n_b), rel=1e-8)
    assert seq["translation_percent"] == pytest.approx(3.0, rel=1e-8)
    assert seq["pooling"] == "sequences" and seq["num_sequences"] == 2
    for row in seq["per_length"]:
        assert row["translation_percent"] == pytest.approx(3.0, rel=1e-8)


def test_matches_a_devkit_style_loop_on_a_noisy_curvy_drive():
    rng = np.random.default_rng(5)
    rel = np.column_stack([rng.uniform(0.5, 3, 700), rng.normal(0, 0.2, 700), rng.normal(0, 0.04, 700)])
    noisy = rel + rng.normal(0, [0.05, 0.05, 0.005], rel.shape)
    gt, est = chain_relative(rel), chain_relative(noisy)
    dist = [0.0]
    for k in range(1, len(gt)):
        dist.append(dist[-1] + math.hypot(*(gt[k, :2, 2] - gt[k - 1, :2, 2])))
    t_errs, r_errs = [], []
    for first in range(0, len(gt), 4):
        for length in M.KITTI_LENGTHS_M:
            last = next((i for i in range(first, len(gt)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            e = np.linalg.inv(np.linalg.inv(est[first]) @ est[last]) @ (np.linalg.inv(gt[first]) @ gt[last])
            t_errs.append(math.hypot(e[0, 2], e[1, 2]) / length)
            r_errs.append(math.acos(max(-1.0, min(1.0, e[0, 0]))) / length)
    m = M.kitti_metrics(gt, est)
    assert m["num_segments"] == len(t_errs) > 0
    assert m["translation_percent"] == pytest.approx(100 * np.mean(t_errs), rel=1e-9)
    assert m["rotation_deg_per_m"] == pytest.approx(math.degrees(np.mean(r_errs)), rel=1e-6)
    # a common change of world frame changes nothing
    world = se2(12.0, -3.0, 0.7)
    moved = M.kitti_metrics(world @ gt, world @ est)
    assert moved["translation_percent"] == pytest.approx(m["translation_percent"], rel=1e-9)


def test_too_short_drive_explains_and_shorter_lengths_work():
    gt = straight(51, step_m=1.0)  # 50 m
    with pytest.raises(ValueError, match=r"shortest segment length is 100 m.*longest drive is 50\.0 m"):
        M.kitti_metrics(gt, gt)
    m = M.kitti_metrics(gt, straight(51, step_m=1.0, scale=1.02), lengths=(10, 20))
    assert [r["length_m"] for r in m["per_length"]] == [10, 20]


def test_bad_inputs_are_explained():
    gt = straight(300)
    with pytest.raises(ValueError, match="pooling"):
        M.kitti_metrics(gt, gt, pooling="frames")
    with pytest.raises(ValueError, match="300 poses but est_poses has 299"):
        M.kitti_metrics(gt, gt[:-1])
    with pytest.raises(ValueError, match=r"\[N, 3, 3\]"):
        M.kitti_metrics(gt[:, :2, :], gt[:, :2, :])
    with pytest.raises(ValueError, match="step"):
        M.kitti_metrics(gt, gt, step=0)


# ----------------------------------------------------------------------------- per-step errors
def test_relative_pose_errors_by_hand():
    gt = np.array([[1.0, 0.0, 0.1], [2.0, 0.5, -0.2]])
    est = np.array([[1.3, -0.4, 0.1 - 2 * np.pi + 0.05], [2.0, 0.5, -0.2]])  # 3-4-5 and a wrapped yaw
    e = M.relative_pose_errors(gt, est)
    np.testing.assert_allclose(e["translation_m"], [0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(e["rotation_rad"], [0.05, 0.0], atol=1e-12)
    np.testing.assert_allclose(e["xyyaw"][0], [0.3, -0.4, 0.05], atol=1e-12)
    assert e["mean_translation_m"] == pytest.approx(0.25) and e["num_steps"] == 2
    assert e["mean_rotation_deg"] == pytest.approx(math.degrees(0.025))
    # absolute poses [N + 1, 3, 3] are read as the N relative poses between them
    e_abs = M.relative_pose_errors(chain_relative(gt), chain_relative(est))
    np.testing.assert_allclose(e_abs["translation_m"], e["translation_m"], atol=1e-12)
    np.testing.assert_allclose(e_abs["rotation_rad"], e["rotation_rad"], atol=1e-12)
    with pytest.raises(ValueError, match="2 steps but est_rel has 1"):
        M.relative_pose_errors(gt, est[:1])


def test_step_biases_by_hand():
    """Scale, direction and yaw RMS of a hand-made set of pairs: two straight moving pairs read
    2 % long and 1° to the left, one turning pair, one standing pair."""
    d = math.radians(1.0)
    gt = np.array([[2.0, 0.0, 0.0], [3.0, 0.0, 0.001], [2.0, 0.1, math.radians(5.0)], [0.1, 0.0, 0.0]])
    est = np.array([
        [2.04 * math.cos(d), 2.04 * math.sin(d), math.radians(0.3)],
        [3.06 * math.cos(d), 3.06 * math.sin(d), 0.001 - math.radians(0.4)],
        [2.0, 0.1, math.radians(5.0)],
        [0.1, 0.0, math.radians(-0.6) + 2 * math.pi],  # wrapped: 0.6° of error
    ])
    b = M.step_biases(gt, est)
    moving_len = 2.0 + 3.0 + math.hypot(2.0, 0.1)
    assert b["scale"] == pytest.approx((2.04 + 3.06 + math.hypot(2.0, 0.1)) / moving_len)
    assert b["direction_deg"] == pytest.approx(1.0, abs=1e-9)
    assert b["num_moving"] == 3 and b["num_straight"] == 2
    assert b["yaw_rms_deg"] == pytest.approx(math.sqrt((0.3**2 + 0.4**2 + 0.0) / 3))
    assert b["yaw_rms_still_deg"] == pytest.approx(0.6)
    # no pair qualifies: NaN, not an error; mismatched lengths: an error naming both
    none = M.step_biases(gt[3:], est[3:])
    assert math.isnan(none["scale"]) and math.isnan(none["direction_deg"]) and math.isnan(none["yaw_rms_deg"])
    with pytest.raises(ValueError, match="4 steps but est_rel has 3"):
        M.step_biases(gt, est[:3])


def test_mahalanobis_by_hand_and_chi_square_mean():
    cov = np.diag([4.0, 1.0, 0.01])[None]
    err = np.array([[2.0, 1.0, 0.1 + 2 * np.pi]])  # each axis one sigma; yaw wraps to 0.1
    assert M.mahalanobis_sq(err, cov)[0] == pytest.approx(3.0, rel=1e-12)
    # e ~ N(0, Σ) with correlated Σ: d² ~ χ²(3), mean 3 (standard error of the mean ≈ 0.017)
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3))
    sigma = a @ a.T + 0.1 * np.eye(3)
    sigma[2] *= 0.01
    sigma[:, 2] *= 0.01  # small yaw variance so that wrapping never triggers
    e = rng.multivariate_normal(np.zeros(3), sigma, size=20000)
    assert M.mean_mahalanobis_sq(e, np.broadcast_to(sigma, (20000, 3, 3))) == pytest.approx(3.0, abs=0.1)
    assert M.mean_mahalanobis_sq(e, np.broadcast_to(4 * sigma, (20000, 3, 3))) == pytest.approx(0.75, abs=0.03)
    with pytest.raises(ValueError, match="singular"):
        M.mahalanobis_sq(err, np.zeros((1, 3, 3)))


def test_mahalanobis_jitter_makes_a_singular_covariance_usable():
    # a one-cell soft-argmax: Σ = 0; the jitter (a thousandth of a cell) sets the scale
    jitter = M.covariance_jitter(resolution_m=0.4, rotation_step_rad=0.01)
    np.testing.assert_allclose(jitter, [(4e-4) ** 2, (4e-4) ** 2, (1e-5) ** 2])
    err = np.array([[4e-4, 0.0, 1e-5]])
    assert M.mahalanobis_sq(err, np.zeros((1, 3, 3)), jitter)[0] == pytest.approx(2.0, rel=1e-9)


def test_segment_errors_with_start_appends_each_segments_first_frame():
    # a 2 % scale error from frame 40 on only: segments starting at or after 40 read 2 %, earlier ones less
    rel = np.tile([STEP_M, 0.0, 0.0], (199, 1))
    est_rel = rel.copy()
    est_rel[40:, 0] *= 1.02
    gt, est = chain_relative(rel), chain_relative(est_rel)
    plain = M.segment_errors(gt, est, step=4, lengths=(20, 50))
    rows = M.segment_errors(gt, est, step=4, lengths=(20, 50), with_start=True)
    assert rows.shape == (len(plain), 4)
    np.testing.assert_array_equal(rows[:, :3], plain)
    for length in (20, 50):
        starts = rows[rows[:, 0] == length, 3]
        np.testing.assert_array_equal(starts, np.arange(0, 200 - length, 4))  # every 4th frame that fits
    late = rows[rows[:, 3] >= 40]
    np.testing.assert_allclose(late[:, 1], 0.02, rtol=1e-6)
    assert np.all(rows[rows[:, 3] + rows[:, 0] <= 40, 1] < 1e-9)  # wholly before the error: none
    assert M.segment_errors(gt[:10], est[:10], lengths=(100,), with_start=True).shape == (0, 4)
