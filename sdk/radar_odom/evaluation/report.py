"""A run's accuracy against its reference: KITTI odometry error (when the drive is long enough for
its segments) and per-step relative errors with the mean Mahalanobis d², as numbers and as text."""
from __future__ import annotations

import numpy as np

KITTI_STEP = 4  # frames between segment starts at 4 Hz (radar convention; devkit uses 10)
KITTI_POOLING = "segments"


def evaluate(gt_poses: np.ndarray, est_poses: np.ndarray, estimates=None,
             jitter_diag=None, gt_relative=None) -> tuple[dict | None, dict]:
    """(KITTI metrics, or None when no segment fits; per-step relative errors).

    The per-step summary also holds the mean Mahalanobis d² of the non-degenerate estimates
    (≈ 3 when the covariance is calibrated) when ``estimates`` are given, computed with
    ``jitter_diag`` added to each covariance as in calibration (`metrics.covariance_jitter`). Steps without
    ground truth (NaN) are left out of the per-step errors (``steps_without_gt`` counts them);
    any of them voids the KITTI metric. ``gt_relative`` (float[N−1, 3], the sequence's own
    relative ground truth) is used for the per-step errors when given, so one missing pair costs
    one step, not every step after it (chained absolute poses are unknown past a gap).
    """
    from ..se2 import relative_from_absolute
    from .metrics import kitti_lengths_for, kitti_metrics, mahalanobis_sq, path_lengths_m, relative_pose_errors

    gt_rel = relative_from_absolute(gt_poses) if gt_relative is None else np.asarray(gt_relative, dtype=np.float64)
    est_rel = relative_from_absolute(est_poses)
    ok = np.all(np.isfinite(gt_rel), axis=1)
    step_errors = {"steps": int(ok.sum())}
    if not ok.all():
        step_errors["steps_without_gt"] = int((~ok).sum())
    if ok.any():
        errors = relative_pose_errors(gt_rel[ok], est_rel[ok])
        # "steps" already counts them (relative_pose_errors' "num_steps" would say it twice)
        step_errors.update({k: v for k, v in errors.items() if not isinstance(v, np.ndarray) and k != "num_steps"})
    if estimates is not None and len(estimates) == len(gt_rel):
        good = ok & np.array([not e.degenerate for e in estimates], dtype=bool)
        if good.any():
            covs = np.stack([e.covariance for e in estimates])[good]
            try:
                d2 = mahalanobis_sq(est_rel[good] - gt_rel[good], covs, jitter_diag)
                step_errors["mean_mahalanobis_d2"] = float(np.mean(d2))
            except ValueError:  # a singular covariance (a hard-argmax-like β): no d²
                pass
    metrics = None
    if ok.all() and np.all(np.isfinite(gt_poses)):
        lengths = kitti_lengths_for(path_lengths_m(gt_poses)[-1])
        try:
            if lengths is not None:
                metrics = kitti_metrics(gt_poses, est_poses, step=KITTI_STEP, pooling=KITTI_POOLING, lengths=lengths)
                metrics["lengths_m"] = list(lengths)
        except ValueError:  # too short for even the shortest segment
            metrics = None
    return metrics, step_errors


def format_metrics(metrics: dict | None, step_errors: dict | None) -> str:
    """Human-readable lines for the metrics (always naming step and pooling)."""
    lines = []
    if metrics is not None:
        lengths = metrics.get("lengths_m")
        seg = f"segments of {lengths[0]:g}–{lengths[-1]:g} m, " if lengths else ""
        lines.append(
            f"KITTI odometry ({seg}step {metrics.get('step', KITTI_STEP)}, pooling "
            f"{metrics.get('pooling', KITTI_POOLING)}, {metrics.get('num_segments', '?')} segments): "
            f"translation {metrics['translation_percent']:.3f} %, rotation {metrics['rotation_deg_per_m']:.5f} deg/m"
        )
    elif step_errors is not None and step_errors.get("steps_without_gt"):
        missing, used = step_errors["steps_without_gt"], step_errors.get("steps", 0)
        lines.append(
            f"KITTI odometry: not computed, {missing} of {missing + used} steps lack ground truth "
            f"(see the warnings); per-step relative errors over the other {used} instead"
        )
    elif step_errors is not None:
        lines.append("KITTI odometry: drive too short for an 80 m segment; per-step relative errors instead")
    if step_errors is not None:
        lines.append("per step: " + ", ".join(f"{k} {v:.4g}" for k, v in step_errors.items()
                                              if isinstance(v, (int, float))))
    return "\n".join(lines)


