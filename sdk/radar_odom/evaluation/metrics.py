"""Odometry accuracy: the KITTI odometry metric as radar papers report it, per-step errors, and
the Mahalanobis calibration check of predicted covariances.

Poses are SE(2) homogeneous float[N, 3, 3] (`radar_odom.se2`), absolute in a common start frame,
x forward / y right (Oxford convention). Relative poses are rows (x m, y m, yaw rad) in the
Oxford convention: the later sweep's frame expressed in the earlier one.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..se2 import invert, relative_from_absolute, wrap_angle

KITTI_LENGTHS_M = (100, 200, 300, 400, 500, 600, 700, 800)
POOLINGS = ("segments", "sequences")


# --------------------------------------------------------------------------- KITTI metric
def kitti_lengths_for(path_length_m: float) -> tuple[int, ...] | None:
    """Segment lengths (m) for a drive of ``path_length_m``: KITTI's 100–800 m where it is long
    enough (≥ 900 m), else eight equal steps up to the largest multiple of 80 m within 90 % of
    the drive (445 m → 50, 100, …, 400; 200 m → 20, …, 160), so a short drive is scored on
    segments of its own scale rather than on the one or two 100 m segments that fit. None when
    even 80 m does not fit (use `relative_pose_errors`)."""
    top = min(KITTI_LENGTHS_M[-1], int(math.floor(0.9 * float(path_length_m) / 80.0)) * 80)
    if top < 80:
        return None
    if top == KITTI_LENGTHS_M[-1]:
        return KITTI_LENGTHS_M
    return tuple(top // 8 * k for k in range(1, 9))


def path_lengths_m(poses: np.ndarray) -> np.ndarray:
    """float64[N]: distance travelled (m) along the positions of poses [N, 3, 3], from 0."""
    steps = np.linalg.norm(np.diff(poses[:, :2, 2], axis=0), axis=1)
    return np.concatenate(([0.0], np.cumsum(steps)))


def segment_errors(gt_poses: np.ndarray, est_poses: np.ndarray, step: int = 4, lengths=KITTI_LENGTHS_M,
                   with_start: bool = False) -> np.ndarray:
    """Every KITTI segment of one sequence: float64[S, 3] rows (length_m, t_err, r_err); with
    ``with_start`` float64[S, 4], the segment's first frame index appended (for resampling
    segments by where they start, e.g. a block bootstrap of a drive's error).

    A segment starts every ``step`` frames; for each length L it ends at the first frame whose
    ground-truth path length exceeds the start's by more than L (none: no segment). With
    ``E = (P_first⁻¹ P_last)⁻¹ (G_first⁻¹ G_last)``, ``t_err = ‖t_E‖ / L`` (m/m) and
    ``r_err = |angle(R_E)| / L`` (rad/m) — divided by the nominal L, as the KITTI devkit does.
    """
    dist = path_lengths_m(gt_poses)
    first = np.arange(0, len(gt_poses), step)
    rows = []
    for length in lengths:
        # searchsorted(side="right") is the first index whose path length is > start + L
        last = np.searchsorted(dist, dist[first] + length, side="right")
        ok = last < len(dist)
        f, e = first[ok], last[ok]
        if f.size == 0:
            continue
        gt_rel = invert(gt_poses[f]) @ gt_poses[e]
        est_rel = invert(est_poses[f]) @ est_poses[e]
        err = invert(est_rel) @ gt_rel
        t_err = np.linalg.norm(err[:, :2, 2], axis=1) / length
        r_err = np.abs(np.arctan2(err[:, 1, 0], err[:, 0, 0])) / length
        cols = [np.full(f.size, float(length)), t_err, r_err] + ([f.astype(np.float64)] if with_start else [])
        rows.append(np.column_stack(cols))
    return np.concatenate(rows) if rows else np.zeros((0, 4 if with_start else 3))


def kitti_metrics(gt_poses, est_poses, step: int = 4, lengths=KITTI_LENGTHS_M, pooling: str = "segments") -> dict:
    """KITTI odometry metric: mean translational error (%) and rotational error (deg/m).

    Args:
        gt_poses, est_poses: absolute SE(2) poses float[N, 3, 3] of one sequence, or lists of
            such arrays (one per sequence, matching lengths pairwise).
        step: a segment starts every ``step`` frames (KITTI devkit: 10; 4 Hz radar papers: 4).
        lengths: segment lengths in metres of ground-truth path. Drives shorter than 100 m can
            pass shorter ones (e.g. ``(10, 20, 30)``), or use `relative_pose_errors`.
        pooling: ``"segments"`` averages all segments of all sequences (KITTI devkit);
            ``"sequences"`` averages each sequence's segments, then the sequences (pyboreas).

    Returns:
        ``{"translation_percent", "rotation_deg_per_m", "step", "pooling", "num_segments",
        "num_sequences", "per_length": [{"length_m", "translation_percent",
        "rotation_deg_per_m", "num_segments"}, ...]}``. Lengths for which no segment fits are
        left out of ``per_length``; sequences with no segment at all are left out of the means
        (``num_sequences`` counts those used). Report the step and pooling with the numbers.

    Raises:
        ConfigError (a ValueError): bad shapes or pooling, or no segment fits any sequence (the message gives
        the shortest length and the longest drive).
    """
    if pooling not in POOLINGS:
        raise ConfigError(f"pooling must be one of {POOLINGS}, got {pooling!r}")
    if int(step) != step or step < 1:
        raise ConfigError(f"step must be a positive integer (frames between segment starts), got {step!r}")
    lengths = tuple(float(x) for x in lengths)
    if not lengths or min(lengths) <= 0:
        raise ConfigError(f"lengths must be positive segment lengths in metres, got {lengths}")
    gts, ests = _as_sequences(gt_poses, "gt_poses"), _as_sequences(est_poses, "est_poses")
    if len(gts) != len(ests):
        raise ConfigError(f"gt_poses holds {len(gts)} sequences but est_poses holds {len(ests)}")
    for i, (g, e) in enumerate(zip(gts, ests)):
        if g.shape != e.shape:
            raise ConfigError(
                f"sequence {i}: gt_poses has {len(g)} poses but est_poses has {len(e)}; give one estimate per gt pose"
            )

    per_seq = [segment_errors(g, e, int(step), lengths) for g, e in zip(gts, ests)]
    used = [s for s in per_seq if len(s)]
    if not used:
        drive = max(path_lengths_m(g)[-1] for g in gts)
        raise ConfigError(
            f"no KITTI segment fits: the shortest segment length is {min(lengths):g} m but the longest "
            f"drive is {drive:.1f} m of ground-truth path; pass shorter lengths=(...) or use "
            "relative_pose_errors() for short drives"
        )

    def pooled(rows_per_seq):
        """(t_err, r_err) means under the chosen pooling, from per-sequence segment rows."""
        rows_per_seq = [r for r in rows_per_seq if len(r)]
        if pooling == "segments":
            allr = np.concatenate(rows_per_seq)
            return allr[:, 1].mean(), allr[:, 2].mean()
        means = np.array([[r[:, 1].mean(), r[:, 2].mean()] for r in rows_per_seq])
        return means[:, 0].mean(), means[:, 1].mean()

    t, r = pooled(used)
    per_length = []
    for length in lengths:
        rows = [s[s[:, 0] == length] for s in used]
        n = sum(len(x) for x in rows)
        if n:
            tl, rl = pooled(rows)
            per_length.append({
                "length_m": length,
                "translation_percent": float(100.0 * tl),  # plain floats: printed as numbers, not np.float64(…)
                "rotation_deg_per_m": float(math.degrees(rl)),
                "num_segments": int(n),
            })
    return {
        "translation_percent": float(100.0 * t),
        "rotation_deg_per_m": float(math.degrees(r)),
        "step": int(step),
        "pooling": pooling,
        "num_segments": int(sum(len(s) for s in used)),
        "num_sequences": len(used),
        "per_length": per_length,
    }


def _as_sequences(poses, name: str) -> list[np.ndarray]:
    """A list of float64[N, 3, 3] arrays from one [N, 3, 3] array or a list of them."""
    if isinstance(poses, np.ndarray) or (isinstance(poses, (list, tuple)) and poses and np.ndim(poses[0]) == 2):
        seqs = [poses]  # one sequence: an array, or a list of 3×3 matrices
    else:
        seqs = list(poses)
    out = []
    for i, p in enumerate(seqs):
        p = np.asarray(p, dtype=np.float64)
        if p.ndim != 3 or p.shape[1:] != (3, 3) or len(p) < 2:
            raise ConfigError(
                f"{name}[{i}] must be SE(2) poses of shape [N, 3, 3] with N >= 2, got {p.shape}; "
                "build them with radar_odom.se2.chain_relative"
            )
        if not np.all(np.isfinite(p)):
            raise ConfigError(f"{name}[{i}] holds NaN/inf poses")
        out.append(p)
    if not out:
        raise ConfigError(f"{name} is empty")
    return out


# --------------------------------------------------------------------------- per-step errors
def relative_pose_errors(gt_rel, est_rel) -> dict:
    """Errors of each relative pose (one per sweep pair), for drives too short for KITTI segments.

    Args:
        gt_rel, est_rel: float[N, 3] Oxford relative poses (x m, y m, yaw rad), or absolute SE(2)
            poses float[N + 1, 3, 3] (turned into the N relative poses between consecutive ones).

    Returns:
        ``"xyyaw"``: float64[N, 3] est − gt, the yaw difference wrapped to (−π, π];
        ``"translation_m"``: float64[N] ‖t_E‖; ``"rotation_rad"``: float64[N] |angle(R_E)|, where
        ``E = est⁻¹ gt`` (so ‖t_E‖ = ‖t_est − t_gt‖ and angle(R_E) = yaw_gt − yaw_est); and the
        summaries ``"mean_translation_m"``, ``"mean_rotation_deg"`` (floats), ``"num_steps"``.
    """
    gt = _as_xyyaw(gt_rel, "gt_rel")
    est = _as_xyyaw(est_rel, "est_rel")
    if gt.shape != est.shape:
        raise ConfigError(f"gt_rel has {len(gt)} steps but est_rel has {len(est)}; give one estimate per pair")
    d = est - gt
    d[:, 2] = wrap_angle(d[:, 2])
    trans_m, rot_rad = np.hypot(d[:, 0], d[:, 1]), np.abs(d[:, 2])
    return {
        "xyyaw": d,
        "translation_m": trans_m,
        "rotation_rad": rot_rad,
        "mean_translation_m": float(trans_m.mean()) if len(d) else math.nan,
        "mean_rotation_deg": math.degrees(rot_rad.mean()) if len(d) else math.nan,
        "num_steps": int(len(d)),
    }


EXACT_ZERO_RAD = 1e-7  # an estimated yaw this close to 0 is the identity candidate itself, not a measurement


def step_biases(gt_rel, est_rel, min_step_m: float = 1.0, straight_deg: float = 0.5,
                turning_deg: float = 0.2) -> dict:
    """Systematic errors of the per-pair estimates, which KITTI segments mix with the random walk
    of the heading: a matcher that reads every step 2 % short, or points its translation 1.5° to
    one side, scores worse however small its noise.

    Args:
        gt_rel, est_rel: as `relative_pose_errors` (N relative poses, or N + 1 absolute ones).
        min_step_m: pairs whose reference translation is shorter are left out (standing still:
            scale and direction are undefined there).
        straight_deg: a pair is "straight" when its reference yaw is within this many degrees.
        turning_deg: a pair is "turning" when its reference yaw exceeds this many degrees.

    Returns:
        ``"scale"``: Σ‖t_est‖ / Σ‖t_gt‖ over the moving pairs (1 = no scale error);
        ``"direction_deg"``: median over straight moving pairs of the estimate's translation
        direction atan2(y, x) minus the reference's (positive = towards +y of the sensor frame);
        ``"yaw_rms_deg"``: RMS of the wrapped yaw error over the moving pairs;
        ``"yaw_rms_still_deg"``: the same over the other pairs (NaN if none);
        ``"yaw_slope"``: Σ yaw_est·yaw_gt / Σ yaw_gt² over the turning pairs (a least-squares
        line through the origin: 1 = turns read in full, below 1 = shrunk toward "no rotation");
        ``"exact_zero_share"``: the share of all pairs whose estimated yaw is exactly 0 (within
        `EXACT_ZERO_RAD`): the search's identity candidate read out without sub-step refinement;
        ``"num_moving"``, ``"num_straight"``, ``"num_turning"`` (ints). NaN where no pair qualifies.
    """
    gt = _as_xyyaw(gt_rel, "gt_rel")
    est = _as_xyyaw(est_rel, "est_rel")
    if gt.shape != est.shape:
        raise ConfigError(f"gt_rel has {len(gt)} steps but est_rel has {len(est)}; give one estimate per pair")
    gt_len = np.hypot(gt[:, 0], gt[:, 1])
    moving = gt_len >= min_step_m
    straight = moving & (np.abs(np.degrees(gt[:, 2])) <= straight_deg)
    yaw_err = np.degrees(wrap_angle(est[:, 2] - gt[:, 2]))

    def rms(a):
        return float(np.sqrt(np.mean(a**2))) if len(a) else math.nan

    direction = np.degrees(wrap_angle(np.arctan2(est[:, 1], est[:, 0]) - np.arctan2(gt[:, 1], gt[:, 0])))
    turning = np.abs(np.degrees(gt[:, 2])) > turning_deg
    return {
        "scale": float(np.hypot(est[moving, 0], est[moving, 1]).sum() / gt_len[moving].sum())
        if moving.any() else math.nan,
        "direction_deg": float(np.median(direction[straight])) if straight.any() else math.nan,
        "yaw_rms_deg": rms(yaw_err[moving]),
        "yaw_rms_still_deg": rms(yaw_err[~moving]),
        "yaw_slope": float(np.sum(est[turning, 2] * gt[turning, 2]) / np.sum(gt[turning, 2] ** 2))
        if turning.any() else math.nan,
        "exact_zero_share": float(np.mean(np.abs(est[:, 2]) < EXACT_ZERO_RAD)) if len(est) else math.nan,
        "num_moving": int(moving.sum()),
        "num_straight": int(straight.sum()),
        "num_turning": int(turning.sum()),
    }


# a soft-argmax at a high β concentrates on one cell and its covariance can be singular; d² is
# computed with this diagonal added, a thousandth of a grid cell (rotation step for yaw)
JITTER_CELLS = 1e-3


def covariance_jitter(resolution_m: float, rotation_step_rad: float) -> np.ndarray:
    """float64[3]: the diagonal ``(JITTER_CELLS · cell)²`` added to Σ before inversion (x, y, yaw)."""
    cell = np.array([resolution_m, resolution_m, rotation_step_rad], dtype=np.float64)
    return (JITTER_CELLS * cell) ** 2


def mahalanobis_sq(err, cov, jitter_diag=None) -> np.ndarray:
    """float64[N]: d² = eᵀ (Σ + diag(jitter))⁻¹ e per row, for errors e [N, 3] (x m, y m, yaw
    rad; the yaw component is wrapped to (−π, π]) and covariances Σ [N, 3, 3] over the same
    (x, y, yaw). ``jitter_diag`` (float[3], e.g. `covariance_jitter`) regularises singular Σ.

    For a calibrated Gaussian estimate d² follows χ² with 3 degrees of freedom: mean 3.
    """
    e = _as_xyyaw(err, "err", allow_absolute=False).copy()
    e[:, 2] = wrap_angle(e[:, 2])
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (len(e), 3, 3):
        raise ConfigError(f"cov must have shape ({len(e)}, 3, 3) to match err, got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ConfigError("cov holds NaN/inf")
    if jitter_diag is not None:
        c = c + np.diag(np.asarray(jitter_diag, dtype=np.float64))
    try:
        sol = np.linalg.solve(c, e[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError as exc:
        raise ConfigError(f"a covariance in cov is singular ({exc}); covariances must be positive definite") from exc
    return np.einsum("ni,ni->n", e, sol)


def mean_mahalanobis_sq(err, cov) -> float:
    """Mean of `mahalanobis_sq`: ≈ 3 when the covariances are calibrated (paper Sec. 4.4)."""
    return float(np.mean(mahalanobis_sq(err, cov)))


def _as_xyyaw(a, name: str, allow_absolute: bool = True) -> np.ndarray:
    """float64[N, 3] rows (x, y, yaw); absolute poses [N + 1, 3, 3] become their N relative poses."""
    a = np.asarray(a, dtype=np.float64)
    if allow_absolute and a.ndim == 3 and a.shape[1:] == (3, 3):
        if not np.all(np.isfinite(a)):
            raise ConfigError(f"{name} holds NaN/inf poses")
        return relative_from_absolute(a)
    if a.ndim != 2 or a.shape[1] != 3:
        also = " or [N + 1, 3, 3] (absolute poses)" if allow_absolute else ""
        raise ConfigError(f"{name} must have shape [N, 3] (x m, y m, yaw rad){also}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} holds NaN/inf")
    return a
