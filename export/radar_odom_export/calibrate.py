"""Covariance calibration (paper Sec. 4.4 and 6.2): tune ``beta_cov`` until mean d² ≈ 3.

The pose is always the soft-argmax at the trained ``beta_pose``; a second temperature
``beta_cov`` shapes only the covariance ``Σ̄`` (eq. 3). For a calibrated Gaussian the squared
Mahalanobis error ``d² = eᵀ Σ̄⁻¹ e`` (``e = p_gt − p̄``, yaw wrapped to (−π, π]) is χ²(3), whose
mean is 3. A larger β sharpens the softmax, shrinks Σ̄ and raises d̄², so d̄²(β) increases with
β (paper: 4.467 → 4268, 2.789 → 2.99, 1.995 → 0.28); we sweep β log-spaced around
``beta_pose`` to bracket d̄² = 3, then bisect in log β until d̄² ∈ [2.7, 3.3].

Singular covariances: a very peaked softmax puts all weight on one candidate and Σ̄ = 0. We
add a diagonal jitter of a thousandth of a grid cell, ``diag((1e-3·res)², (1e-3·res)²,
(1e-3·δψ)²)``, before inverting: negligible against any real spread (a cell is the smallest
spread the grid can express) yet it keeps d² finite — and huge, as it should be, for an
over-confident β.

The correlation volumes are computed once per pair; every β then costs only a softmax.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from radar_odom import metrics
from radar_odom.errors import RadarOdomError
from radar_odom.profiles import GridProfile

from .softargmax import candidate_weights, read_pose, weighted_covariance

TARGET_D2 = 3.0
BAND = (2.7, 3.3)
JITTER_CELLS = metrics.JITTER_CELLS


class CalibrationError(RadarOdomError, RuntimeError):
    """No temperature brings mean d² into the target band (the table says why)."""


@dataclass
class CalibrationResult:
    beta_cov: float
    mean_d2: float
    table: list[tuple[float, float]]  # (beta, mean d²), sorted by beta
    pairs: int
    scenario_table: str = ""

    def to_dict(self) -> dict:
        return {"beta_cov": self.beta_cov, "mean_d2": self.mean_d2, "pairs": self.pairs,
                "target": TARGET_D2, "band": list(BAND), "jitter_cells": JITTER_CELLS,
                "table": [[b, d] for b, d in self.table]}


# ----------------------------------------------------------------------------- maths
def covariance_jitter(profile: GridProfile) -> np.ndarray:
    """float64[3]: the diagonal added to Σ̄ before inversion (module docstring)."""
    return metrics.covariance_jitter(profile.resolution_m, profile.rotation_step_rad)


def pose_errors(gt_xyyaw: np.ndarray, mean_xyyaw: np.ndarray) -> np.ndarray:
    """float64[P, 3]: ``gt − mean`` with the yaw difference wrapped to (−π, π]."""
    e = np.asarray(gt_xyyaw, np.float64) - np.asarray(mean_xyyaw, np.float64)
    e[:, 2] = -((-e[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    return e


def mahalanobis_sq(err: np.ndarray, cov: np.ndarray, jitter_diag: np.ndarray | None = None) -> np.ndarray:
    """float64[P]: ``eᵀ (Σ + diag(jitter))⁻¹ e`` for errors [P, 3] and covariances [P, 3, 3]
    (`radar_odom.metrics.mahalanobis_sq`, the one the runtime reports)."""
    return metrics.mahalanobis_sq(err, cov, jitter_diag)


# ----------------------------------------------------------------------------- volumes
@torch.no_grad()
def collect_volumes(model, drives: Sequence, batch: int = 8, max_pairs: int | None = None,
                    progress_desc: str | None = "correlation volumes", with_names: bool = False):
    """(volumes float32[P, K, N, N], gt float64[P, 3]) over the pairs of ``drives`` (and, with
    ``with_names``, each pair's drive name as a third item)."""
    from radar_odom._progress import progress

    pairs = [(d, k) for d in drives for k in range(d.num_pairs)]
    if max_pairs is not None and len(pairs) > max_pairs:
        # evenly spaced so every drive (and scenario) stays represented
        pick = np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)
        pairs = [pairs[i] for i in pick]
    vols, gts = [], []
    bar = progress(total=len(pairs), desc=progress_desc, unit="pair", disable=progress_desc is None)
    for s in range(0, len(pairs), batch):
        chunk = pairs[s : s + batch]
        prev = torch.from_numpy(np.stack([d.images[k] for d, k in chunk]).astype(np.float32))
        cur = torch.from_numpy(np.stack([d.images[k + 1] for d, k in chunk]).astype(np.float32))
        vols.append(model.correlation_volume(prev, cur).float())
        gts.append(np.stack([d.poses_rel[k] for d, k in chunk]))
        bar.update(len(chunk))
    bar.close()
    out = (torch.cat(vols), np.concatenate(gts).astype(np.float64))
    return (*out, [d.name for d, _ in pairs]) if with_names else out


class D2Curve:
    """d̄²(β) over fixed volumes: the pose at ``beta_pose`` once, Σ̄ at each β on demand."""

    def __init__(self, volumes: torch.Tensor, gt_xyyaw: np.ndarray, candidates: torch.Tensor,
                 profile: GridProfile, chunk: int = 64):
        self.volumes = volumes
        self.flat = candidates.reshape(-1, 3).to(torch.float64)
        self.chunk = chunk
        self.jitter = covariance_jitter(profile)
        self.floor = np.diag(profile.covariance_floor)  # as MaskedCorrelator.pose_from_volume adds
        # the pose the model reports (`softargmax.read_pose`)
        means = [read_pose(v.double(), candidates, profile) for v in volumes.split(chunk)]
        self.mean = torch.cat(means).numpy()
        self.err = pose_errors(gt_xyyaw, self.mean)

    def covariances(self, beta: float) -> np.ndarray:
        covs = [
            weighted_covariance(candidate_weights(v.double(), beta), self.flat) for v in self.volumes.split(self.chunk)
        ]
        return torch.cat(covs).numpy() + self.floor

    def d2(self, beta: float) -> np.ndarray:
        return mahalanobis_sq(self.err, self.covariances(beta), self.jitter)

    def __call__(self, beta: float) -> float:
        return float(np.mean(self.d2(beta)))


# ----------------------------------------------------------------------------- search
def calibrate_beta(
    mean_d2: Callable[[float], float],
    beta0: float,
    band=BAND,
    target: float = TARGET_D2,
    decades: tuple[float, float] = (-4.0, 2.0),
    per_decade: int = 2,
    max_decades: float = 12.0,
    max_bisections: int = 60,
) -> CalibrationResult:
    """Find β with ``mean_d2(β)`` in ``band`` (aiming at ``target``), assuming it grows with β.

    1. a log-spaced sweep ``beta0·10^decades`` (``per_decade`` points per decade), widened a
       decade at a time (up to ``max_decades``) until it brackets ``target``;
    2. bisection in log β inside the first bracket until the value is within ``band`` and
       within a tenth of the band's half-width of ``target`` (or the bracket is 1e-6 wide).
    Returns every evaluated (β, d̄²) as the table; raises `CalibrationError` if no bracket.
    """
    if beta0 <= 0 or not math.isfinite(beta0):
        raise ValueError(f"beta0 must be a positive number, got {beta0}")
    table: dict[float, float] = {}

    def f(beta: float) -> float:
        if beta not in table:
            v = mean_d2(beta)
            table[beta] = v if math.isfinite(v) else math.inf
        return table[beta]

    lo_dec, hi_dec = decades
    for e in np.arange(lo_dec, hi_dec + 1e-9, 1.0 / per_decade):
        f(beta0 * 10.0**e)

    def bracket():
        items = sorted(table.items())
        for (b0, v0), (b1, v1) in zip(items, items[1:]):
            if v0 <= target <= v1:
                return b0, b1
        return None

    while bracket() is None:
        items = sorted(table.items())
        if items[0][1] > target and lo_dec > -max_decades:  # even the smallest β is too sharp
            lo_dec -= 1
            f(beta0 * 10.0**lo_dec)
        elif items[-1][1] < target and hi_dec < max_decades:  # even the largest β is too broad
            hi_dec += 1
            f(beta0 * 10.0**hi_dec)
        else:
            raise CalibrationError(
                "no temperature brings mean d² to 3 (d̄² never crosses 3 between "
                f"β={items[0][0]:.3g} and β={items[-1][0]:.3g}):\n{format_table(items)}"
            )
    lo, hi = bracket()
    half = (band[1] - band[0]) / 2
    best = min(table.items(), key=lambda kv: abs(kv[1] - target))
    for _ in range(max_bisections):
        if band[0] <= best[1] <= band[1] and abs(best[1] - target) <= 0.1 * half:
            break
        if math.log(hi / lo) < 1e-6:
            break
        mid = math.sqrt(lo * hi)
        v = f(mid)
        if v < target:
            lo = mid
        else:
            hi = mid
        if abs(v - target) < abs(best[1] - target):
            best = (mid, v)
    if not band[0] <= best[1] <= band[1]:
        raise CalibrationError(
            f"closest mean d² is {best[1]:.3g} at β={best[0]:.4g}, outside {band} (d̄² jumps across 3: "
            f"too few pairs?):\n{format_table(sorted(table.items()))}"
        )
    return CalibrationResult(
        beta_cov=float(best[0]),
        mean_d2=float(best[1]),
        table=sorted((float(b), float(v)) for b, v in table.items()),
        pairs=0,
    )


def format_table(table, chosen: float | None = None) -> str:
    """Markdown table β → mean d², like the paper's (the chosen β in bold)."""
    lines = ["| β (beta_cov) | mean d² |", "|---:|---:|"]
    for b, v in sorted(table, reverse=True):
        mark = "**" if chosen is not None and b == chosen else ""
        lines.append(f"| {mark}{b:.4g}{mark} | {mark}{v:.4g}{mark} |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- checkpoint
def scenario_d2_table(curve: D2Curve, names: Sequence[str], beta: float) -> str:
    """Markdown: mean / median d² and translation error per scenario (drive name prefix) at β."""
    d2 = curve.d2(beta)
    scen = np.array([n.rsplit("-", 1)[0] for n in names])
    lines = ["| scenario | pairs | mean d² | median d² | mean translation error m |", "|---|---:|---:|---:|---:|"]
    for sc in dict.fromkeys(scen):
        sel = scen == sc
        lines.append(
            f"| {sc} | {int(sel.sum())} | {d2[sel].mean():.3g} | {np.median(d2[sel]):.3g} "
            f"| {np.hypot(*curve.err[sel, :2].T).mean():.3f} |"
        )
    return "\n".join(lines)


def calibrate_checkpoint(
    path,
    drives,
    output=None,
    batch: int = 8,
    max_pairs: int | None = 2000,
    info: dict | None = None,
    pose_estimator: str | None = None,
) -> CalibrationResult:
    """Calibrate a checkpoint's ``beta_cov`` on held-out ``drives``; write it in place or to ``output``.

    ``pose_estimator`` ("soft-argmax" | "parabolic"), if given, is set in the profile first (the
    covariance is calibrated against the errors of the pose the model will report)."""
    from dataclasses import asdict

    from .checkpoint import model_from_dict, read_checkpoint_dict, write_checkpoint_dict

    ckpt = read_checkpoint_dict(path)
    if pose_estimator:
        ckpt["profile"] = {**ckpt["profile"], "pose_estimator": pose_estimator}
    model = model_from_dict(ckpt, source=str(path))
    volumes, gt, names = collect_volumes(model, drives, batch=batch, max_pairs=max_pairs, with_names=True)
    curve = D2Curve(volumes, gt, model.candidates, model.profile)
    result = calibrate_beta(curve, model.profile.beta_pose)
    result.pairs = int(len(gt))
    result.scenario_table = scenario_d2_table(curve, names, result.beta_cov)
    profile = model.profile.with_(beta_cov=result.beta_cov)
    ckpt["profile"] = asdict(profile)
    ckpt["calibration"] = {
        **result.to_dict(),
        **(info or {}),
        "drives": [d.name for d in drives],
        "per_scenario": result.scenario_table,
    }
    write_checkpoint_dict(output or path, ckpt)
    return result


def run_from_args(args) -> CalibrationResult:
    """`radar-odom calibrate`: held-out drives on the checkpoint's grid, then `calibrate_checkpoint`."""
    import shlex
    import sys

    from radar_odom.profiles import GridProfile

    from .checkpoint import read_checkpoint_dict
    from .data import build_drives, check_seed_policy, parse_seeds, sequence_drives, sim_specs

    if args.threads:
        torch.set_num_threads(args.threads)
    profile = GridProfile.from_dict(read_checkpoint_dict(args.checkpoint)["profile"])
    info = {"command": "radar-odom " + " ".join(shlex.quote(a) for a in sys.argv[1:])}
    if args.data:
        drives = [d for p in args.data for d in sequence_drives(p, profile)]
        info["data"] = [str(p) for p in args.data]
    else:
        seeds = parse_seeds(args.sim_seeds)
        check_seed_policy(seeds, "val")
        scenarios = [s for s in args.scenarios.split(",") if s]
        drives = build_drives(
            profile,
            sim_specs(seeds, scenarios, args.frames),
            args.workers,
            with_labels=False,
            desc="calibration drives",
        )
        info.update(sim_seeds=seeds, scenarios=scenarios, frames=args.frames)
    result = calibrate_checkpoint(
        args.checkpoint,
        drives,
        output=args.output,
        batch=args.batch,
        max_pairs=args.max_pairs,
        info=info,
        pose_estimator=getattr(args, "pose_estimator", None),
    )
    print(format_table(result.table, chosen=result.beta_cov))
    print("\nper scenario at the chosen β:\n" + result.scenario_table)
    print(
        f"\nbeta_cov = {result.beta_cov:.4g} -> mean d² = {result.mean_d2:.3f} over {result.pairs} pairs "
        f"(beta_pose = {profile.beta_pose:g}); written to {args.output or args.checkpoint}"
    )
    return result
