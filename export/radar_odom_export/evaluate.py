"""Evaluate checkpoints on held-out drives: KITTI errors, mean d², runtime per pair.

For each drive the model estimates every consecutive pair (the pose at ``beta_pose``, the
covariance at ``beta_cov``); estimates are chained into a trajectory (`se2.chain_relative`)
and scored with `radar_odom.evaluation.metrics.kitti_metrics` against the chained ground truth. Mean d²
uses the jittered inverse calibration uses too (`mahalanobis_sq`).

Single-mode Cartesian models are run the way a stream runs them: each sweep is masked, rotated
and transformed once, and pair k correlates sweep k's unrotated spectrum with sweep k+1's
rotated stack (`MaskedCorrelator.stream_step` maths, batched). Other modes use the pair form.
Runtime is the median wall time of ``stream_step`` on one sweep (batch 1) after warm-up, in
torch on this CPU with the FFT backend — the ONNX runtime numbers come from
``radar-odom profile``.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np
import torch

from radar_odom.evaluation import metrics
from radar_odom.se2 import chain_relative


def covariance_jitter(profile) -> np.ndarray:
    """float64[3]: the diagonal added to Σ̄ before inversion (`radar_odom.evaluation.metrics.covariance_jitter`)."""
    return metrics.covariance_jitter(profile.resolution_m, profile.rotation_step_rad)


def pose_errors(gt_xyyaw: np.ndarray, mean_xyyaw: np.ndarray) -> np.ndarray:
    """float64[P, 3]: ``gt − mean`` with the yaw difference wrapped to (−π, π]."""
    e = np.asarray(gt_xyyaw, np.float64) - np.asarray(mean_xyyaw, np.float64)
    e[:, 2] = -((-e[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    return e


def mahalanobis_sq(err: np.ndarray, cov: np.ndarray, jitter_diag: np.ndarray | None = None) -> np.ndarray:
    """float64[P]: ``eᵀ (Σ + diag(jitter))⁻¹ e`` (`radar_odom.evaluation.metrics.mahalanobis_sq`, the one the
    runtime reports)."""
    return metrics.mahalanobis_sq(err, cov, jitter_diag)


@torch.no_grad()
def estimate_drive(model, images: np.ndarray, batch: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(poses float64[F-1, 3], covariances float64[F-1, 3, 3]) for consecutive sweeps [F, W, W]."""
    poses, covs = [], []
    p = model.profile
    streamable = p.mode == "single" and p.input_kind == "cartesian" and model.masking in ("learned", "raw", "cfar")
    corr, rot = model.correlation, model.rotator
    prev_state = None
    for s in range(0, len(images), batch):
        x = torch.from_numpy(np.asarray(images[s : s + batch], dtype=np.float32))
        if streamable:
            # features (mask, support disc) as stream_step makes them; [b, K, 2, W, G] once per sweep
            features = model.sweep_features(x)
            spectra = corr.spectrum(rot(features))
            states = model.state_of(features, spectra)
            prevs = states[:-1] if prev_state is None else torch.cat([prev_state, states[:-1]])
            curs = spectra[1:] if prev_state is None else spectra
            if len(curs):
                pose, cov = model.pose_from_volume(corr.correlate(prevs, curs))
                poses.append(pose)
                covs.append(cov)
            prev_state = states[-1:]
        else:
            prev = x[:-1] if prev_state is None else torch.cat([prev_state, x[:-1]])
            cur = x[1:] if prev_state is None else x
            if len(cur):
                pose, cov = model(prev, cur)
                poses.append(pose)
                covs.append(cov)
            prev_state = x[-1:]
    return (torch.cat(poses).double().numpy(), torch.cat(covs).double().numpy())


@torch.no_grad()
def runtime_per_pair_ms(model, images: np.ndarray, repeats: int = 20, warmup: int = 3) -> float:
    """Median ms of one streaming step (mask + rotate + correlate + soft-argmax), batch 1."""
    x = torch.from_numpy(np.asarray(images[: repeats + warmup + 1], dtype=np.float32))
    if len(x) < 2:
        return float("nan")
    single = model.profile.mode == "single"
    state = model.initial_state(x[:1]) if single else x[:1]
    times = []
    for k in range(1, len(x)):
        t0 = time.perf_counter()
        if single:
            _, _, state = model.stream_step(x[k : k + 1], state)
        else:
            model(state, x[k : k + 1])
            state = x[k : k + 1]
        times.append(time.perf_counter() - t0)
    return 1000.0 * float(np.median(times[warmup:] if len(times) > warmup else times))


def with_motion_prior(poses: np.ndarray, covs: np.ndarray, dt_s: float = 0.25,
                      config=None) -> tuple[np.ndarray, np.ndarray]:
    """The runtime's motion prior (`radar_odom.odometry.motion_prior.MotionPrior`, default settings or
    ``config``, a `MotionPriorConfig`) run over a drive's measurements in order: fused poses
    float64[P, 3] and reported covariances [P, 3, 3]."""
    from radar_odom.odometry.motion_prior import MotionPrior

    prior = MotionPrior(config)
    out_p, out_c = [], []
    for m, c in zip(poses, covs):
        st = prior.update(m, c, dt_s)
        out_p.append(st.pose)
        out_c.append(st.covariance)
    return np.asarray(out_p, np.float64), np.asarray(out_c, np.float64)


def evaluate_model(model, drives: Sequence, step: int = 4, lengths=(100, 200), pooling: str = "segments",
                   batch: int = 8, timing_repeats: int = 20, progress_desc: str | None = None,
                   motion_prior: bool = False, estimates: list | None = None, prior_config=None) -> dict:
    """KITTI metrics over all drives (and per scenario), mean d², runtime; a JSON-able dict.

    Drive names ``scenario-seed`` group drives by scenario for the per-scenario rows. With
    ``motion_prior`` the measurements are fused by the runtime's motion prior first (as
    `RadarOdometer` does by default; simulated drives are 4 Hz). ``estimates`` (a list of
    (poses, covs) per drive, as `estimate_drive` returns) skips the model; the result's
    ``"estimates"`` holds the model's own, for a second call. ``prior_config``: a
    `MotionPriorConfig` for the prior (default: the runtime's).
    """
    from radar_odom._progress import progress
    from radar_odom.evaluation.metrics import kitti_metrics

    jitter = covariance_jitter(model.profile)
    gt_abs, est_abs, d2_all, per_drive, raw_estimates = [], [], [], [], []
    for i, d in enumerate(progress(drives, desc=progress_desc, unit="drive", disable=progress_desc is None)):
        poses, covs = estimates[i] if estimates is not None else estimate_drive(model, d.images, batch)
        raw_estimates.append((poses, covs))
        if motion_prior:
            poses, covs = with_motion_prior(poses, covs, config=prior_config)
        gt = d.poses_rel.astype(np.float64)
        d2 = mahalanobis_sq(pose_errors(gt, poses), covs, jitter)
        gt_abs.append(chain_relative(gt))
        est_abs.append(chain_relative(poses))
        d2_all.append(d2)
        err = np.abs(pose_errors(gt, poses))
        per_drive.append({"drive": d.name, "pairs": d.num_pairs, "path_m": d.path_length_m(),
                          "mean_abs_err_xyyaw": err.mean(0).tolist(), "mean_d2": float(d2.mean())})

    def kitti(idx):
        try:
            return kitti_metrics([gt_abs[i] for i in idx], [est_abs[i] for i in idx], step=step,
                                 lengths=lengths, pooling=pooling)
        except ValueError as exc:  # drives too short for any segment
            return {"translation_percent": math.nan, "rotation_deg_per_m": math.nan, "error": str(exc)}

    overall = kitti(range(len(drives)))
    scenarios: dict[str, list[int]] = {}
    for i, d in enumerate(drives):
        scenarios.setdefault(d.name.rsplit("-", 1)[0], []).append(i)
    per_scenario = {}
    for sc, idx in scenarios.items():
        k = kitti(idx)
        per_scenario[sc] = {"translation_percent": k["translation_percent"],
                            "rotation_deg_per_m": k["rotation_deg_per_m"],
                            "mean_d2": float(np.concatenate([d2_all[i] for i in idx]).mean())}
    d2 = np.concatenate(d2_all)
    return {
        "resolution_m": model.profile.resolution_m,
        "profile": model.profile.name,
        "masking": model.masking,
        "translation_percent": overall["translation_percent"],
        "rotation_deg_per_m": overall["rotation_deg_per_m"],
        "kitti": overall,
        "mean_d2": float(d2.mean()),
        "median_d2": float(np.median(d2)),
        "beta_pose": model.profile.beta_pose,
        "beta_cov": model.profile.beta_cov,
        "runtime_ms_per_pair": (runtime_per_pair_ms(model, drives[0].images, timing_repeats)
                                if drives and timing_repeats else math.nan),
        "motion_prior": bool(motion_prior),
        "estimates": raw_estimates,
        "threads": torch.get_num_threads(),
        "per_scenario": per_scenario,
        "per_drive": per_drive,
        "step": step,
        "lengths_m": list(lengths),
        "pooling": pooling,
    }


def markdown_table(rows: Sequence[dict]) -> str:
    """The README results table: one row per evaluated model (``rows[i]["label"]`` names it)."""
    lines = [
        "| model | m/px | trans. err % | rot. err deg/m | mean d² | runtime ms/pair |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        d2 = f"{r['mean_d2']:.3g}" + ("" if r.get("calibrated") else " (uncal.)")
        lines.append(
            f"| {r['label']} | {r['resolution_m']:g} | {r['translation_percent']:.3f} | "
            f"{r['rotation_deg_per_m']:.4f} | {d2} | {r['runtime_ms_per_pair']:.1f} |"
        )
    return "\n".join(lines)


def _per_scenario_table(rows: Sequence[dict], key: str, fmt: str) -> str:
    """One per-scenario metric ``key`` (columns: scenarios) for each model (rows)."""
    scen = sorted({s for r in rows for s in r["per_scenario"]})
    lines = ["| model | " + " | ".join(scen) + " |", "|---|" + "---:|" * len(scen)]
    for r in rows:
        vals = [r["per_scenario"].get(s, {}).get(key, math.nan) for s in scen]
        lines.append(f"| {r['label']} | " + " | ".join(format(v, fmt) for v in vals) + " |")
    return "\n".join(lines)


def scenario_table(rows: Sequence[dict]) -> str:
    """Translational error % per scenario (columns) for each model (rows)."""
    return _per_scenario_table(rows, "translation_percent", ".2f")


def scenario_d2_table(rows: Sequence[dict]) -> str:
    """Mean d² per scenario (columns) for each model (rows): is the covariance honest everywhere?"""
    return _per_scenario_table(rows, "mean_d2", ".3g")
