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

**Per-axis shape** (`fit_covariance_shape`, the default after the temperature): one temperature
cannot be right for both a sharp peak and a corridor's ridge. With the parabolic read-out the
pose is sub-cell precise wherever the peak is sharp, so the quantisation floor (a whole cell's
variance) makes urban covariances ~10× too large in variance while a ridge's moment is too small.
The model reports ``Σ = s·M + diag(c_t²·res², c_t²·res², c_ψ²·δψ²)/12`` (M: the beta_cov
moment; ``cov_scale`` s, ``cov_floor_cells`` c_t, ``cov_floor_yaw_cells`` c_ψ), and the three
are fitted by Gaussian maximum likelihood, ``min Σᵢ dᵢ² + log det Σᵢ``, on every consecutive
pair of the calibration drives as the search the model will be exported with computes them
(the fast search's moments differ from the exhaustive volume's). The family is closed under a
common scale, so at the optimum mean d² = 3 on those pairs exactly; the per-scenario table shows
the balance the floors and the scale buy.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from radar_odom.errors import RadarOdomError
from radar_odom.evaluation import metrics
from radar_odom.profiles import GridProfile

from .checkpoint import provenance_command
from .evaluate import covariance_jitter, estimate_drive, mahalanobis_sq, pose_errors  # noqa: F401 (re-exported)
from .softargmax import candidate_weights, read_pose, weighted_covariance

TARGET_D2 = 3.0
BAND = (2.7, 3.3)
JITTER_CELLS = metrics.JITTER_CELLS
REAL_PREFIX = "real:"  # drive names of real recordings (`real_pairs.real_runs`)
# how a --minutes budget is spent (`run_from_args`): simulating the drives within its first CAL_SIM_SHARE; the
# correlation volumes (temperature) and the search estimates (per-axis shape) share the time left until
# CAL_WORK_SHARE of it (`radar-odom export` leaves itself EXPORT_WORK_SHARE, the rest for writing the ONNX file);
# each stage takes as many pairs, spread over every drive, as it expects to finish in its time, at least one batch
CAL_SIM_SHARE = 0.25
CAL_WORK_SHARE = 0.9
EXPORT_WORK_SHARE = 0.7


class CalibrationError(RadarOdomError, RuntimeError):
    """No temperature brings mean d² into the target band (the table says why; ``table``: the (β, d̄²) tried)."""

    def __init__(self, message: str, table=()):
        super().__init__(message)
        self.table = [(float(b), float(v)) for b, v in table]


@dataclass
class CalibrationResult:
    beta_cov: float
    mean_d2: float
    table: list[tuple[float, float]]  # (beta, mean d²), sorted by beta
    pairs: int
    scenario_table: str = ""
    shape: CovarianceShape | None = None  # the per-axis fit, when made (mean_d2 is then its own)
    # under a budget: {"volumes": [pairs used, pairs there], "estimates": [...]} (`calibrate_checkpoint`)
    coverage: dict = field(default_factory=dict)
    note: str = ""  # where the temperature fell back to beta_pose (`calibrate_checkpoint`)

    def to_dict(self) -> dict:
        return {"beta_cov": self.beta_cov, "mean_d2": self.mean_d2, "pairs": self.pairs,
                "target": TARGET_D2, "band": list(BAND), "jitter_cells": JITTER_CELLS,
                "table": [[b, d] for b, d in self.table],
                "shape": None if self.shape is None else self.shape.to_dict(),
                **({"coverage": self.coverage} if self.coverage else {}),
                **({"note": self.note} if self.note else {})}


@dataclass
class CovarianceShape:
    """`fit_covariance_shape`'s result: the profile fields and how they score on the fit's pairs."""

    cov_scale: float
    cov_floor_cells: float
    cov_floor_yaw_cells: float
    mean_d2: float  # on the pairs fitted (3 at the optimum)
    pairs: int
    search: str = "exhaustive"
    real_share: float | None = None  # the real pairs' share of the likelihood (None: no real pairs)

    def profile_fields(self) -> dict:
        return {"cov_scale": self.cov_scale, "cov_floor_cells": self.cov_floor_cells,
                "cov_floor_yaw_cells": self.cov_floor_yaw_cells}

    def to_dict(self) -> dict:
        return {**self.profile_fields(), "mean_d2": self.mean_d2, "pairs": self.pairs, "search": self.search,
                "real_share": self.real_share}


# ----------------------------------------------------------------------------- budgets
def spread_order(n: int) -> list[int]:
    """``range(n)`` reordered so that every prefix is spread over the whole range (strides of ⌈√n⌉, then the
    strides shifted by one, ...): work cut short by a budget still covers every drive it can."""
    step = max(1, math.ceil(math.sqrt(n)))
    return [i for r in range(step) for i in range(r, n, step)]


class _Clock:
    """Whether another unit of work (a batch, a window) may start before ``deadline``: the first always; then
    while now + the mean unit so far ends by it. ``deadline`` None: always."""

    def __init__(self, deadline: float | None):
        self.deadline, self.spent, self.units, self.t = deadline, 0.0, 0, None

    def may_start(self) -> bool:
        self.t = time.perf_counter()
        return self.deadline is None or self.units == 0 or self.t + self.spent / self.units <= self.deadline

    def done(self) -> None:
        self.spent += time.perf_counter() - self.t
        self.units += 1


# ----------------------------------------------------------------------------- volumes
@torch.no_grad()
def collect_volumes(model, drives: Sequence, batch: int = 8, max_pairs: int | None = None,
                    progress_desc: str | None = "correlation volumes", with_names: bool = False,
                    deadline: float | None = None, coverage: dict | None = None):
    """(volumes float32[P, K, N, N], gt float64[P, 3]) over the pairs of ``drives`` (and, with
    ``with_names``, each pair's drive name as a third item).

    ``deadline`` (a `time.perf_counter` value): the pairs are taken in `spread_order`, a batch at a time, while
    the next batch is expected to end by it (at least one batch). ``coverage`` (a dict) receives
    ``"volumes": [pairs used, pairs there]``."""
    from radar_odom._progress import progress

    pairs = [(d, k) for d in drives for k in range(d.num_pairs)]
    there = len(pairs)
    if max_pairs is not None and len(pairs) > max_pairs:
        # evenly spaced so every drive (and scenario) stays represented
        pick = np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)
        pairs = [pairs[i] for i in pick]
    if deadline is not None:
        pairs = [pairs[i] for i in spread_order(len(pairs))]
    vols, gts, used = [], [], []
    clock = _Clock(deadline)
    bar = progress(total=len(pairs), desc=progress_desc, unit="pair", disable=progress_desc is None)
    for s in range(0, len(pairs), batch):
        if not clock.may_start():
            break
        chunk = pairs[s : s + batch]
        used += chunk
        prev = torch.from_numpy(np.stack([d.images[k] for d, k in chunk]).astype(np.float32))
        cur = torch.from_numpy(np.stack([d.images[k + 1] for d, k in chunk]).astype(np.float32))
        vols.append(model.correlation_volume(prev, cur).float())
        gts.append(np.stack([d.poses_rel[k] for d, k in chunk]))
        bar.update(len(chunk))
        clock.done()
    bar.close()
    if coverage is not None:
        coverage["volumes"] = [len(used), there]
    out = (torch.cat(vols), np.concatenate(gts).astype(np.float64))
    return (*out, [d.name for d, _ in used]) if with_names else out


class D2Curve:
    """d̄²(β) over fixed volumes: the pose at ``beta_pose`` once, Σ̄ at each β on demand."""

    def __init__(self, volumes: torch.Tensor, gt_xyyaw: np.ndarray, candidates: torch.Tensor,
                 profile: GridProfile, chunk: int = 64):
        self.volumes = volumes
        self.flat = candidates.reshape(-1, 3).to(torch.float64)
        self.chunk = chunk
        self.jitter = covariance_jitter(profile)
        self.profile = profile  # its scale and floor, as MaskedCorrelator.covariance_from_moment
        # the pose the model reports (`softargmax.read_pose`)
        means = [read_pose(v.double(), candidates, profile) for v in volumes.split(chunk)]
        self.mean = torch.cat(means).numpy()
        self.err = pose_errors(gt_xyyaw, self.mean)

    def covariances(self, beta: float) -> np.ndarray:
        covs = [
            weighted_covariance(candidate_weights(v.double(), beta), self.flat) for v in self.volumes.split(self.chunk)
        ]
        return shape_covariances(torch.cat(covs).numpy(), self.profile)

    def d2(self, beta: float) -> np.ndarray:
        return mahalanobis_sq(self.err, self.covariances(beta), self.jitter)

    def __call__(self, beta: float) -> float:
        return float(np.mean(self.d2(beta)))


# ----------------------------------------------------------------------------- per-axis shape
def shape_covariances(moments: np.ndarray, profile: GridProfile) -> np.ndarray:
    """float64[P, 3, 3] ``cov_scale · M + covariance_floor`` for moments M [P, 3, 3] (as the model):
    `GridProfile.covariance_from_moment`."""
    return profile.covariance_from_moment(moments)


def fit_covariance_shape(moments: np.ndarray, errors: np.ndarray, profile: GridProfile,
                         iterations: int = 4, weights: np.ndarray | None = None) -> CovarianceShape:
    """Maximum-likelihood ``cov_scale``, ``cov_floor_cells`` and ``cov_floor_yaw_cells``.

    Args:
        moments: float[P, 3, 3] beta_cov second moments (m², m·rad, rad²), no scale or floor.
        errors: float[P, 3] ``gt − pose`` (x m, y m, yaw rad; yaw wrapped).
        profile: for the cell sizes (``resolution_m``, ``rotation_step_rad``).
        weights: float[P] ≥ 0, each pair's share of the likelihood (None: equal). Lets a few
            hundred real pairs count as much as thousands of simulated ones (`pair_weights`).
    Returns:
        `CovarianceShape` minimising the (weighted) Gaussian negative log-likelihood
        ``Σᵢ wᵢ (dᵢ² + log det Σᵢ)`` over the pairs (L-BFGS on the logs, so all three stay
        positive), with the (weighted) mean d² it gives there: 3 at the optimum.
    """
    m = torch.as_tensor(np.asarray(moments, np.float64))
    e = torch.as_tensor(np.asarray(errors, np.float64))
    if m.ndim != 3 or m.shape[1:] != (3, 3) or e.shape != (m.shape[0], 3) or len(e) < 3:
        raise ValueError(f"need moments [P, 3, 3] and errors [P, 3] with P >= 3, "
                         f"got {tuple(m.shape)}, {tuple(e.shape)}")
    w_np = np.ones(len(e)) if weights is None else np.asarray(weights, np.float64)
    if w_np.shape != (len(e),) or not np.all(np.isfinite(w_np)) or np.any(w_np < 0) or w_np.sum() <= 0:
        raise ValueError(f"weights must be {len(e)} finite values >= 0 with a positive sum")
    w_np = w_np / w_np.sum()
    w = torch.as_tensor(w_np)
    cell2 = torch.tensor([profile.resolution_m, profile.resolution_m, profile.rotation_step_rad],
                         dtype=torch.float64) ** 2 / 12.0
    # start from the paper's form (scale 1, one cell's floor)
    theta = torch.zeros(3, dtype=torch.float64, requires_grad=True)  # log s, log c_t², log c_ψ²
    opt = torch.optim.LBFGS([theta], max_iter=200, line_search_fn="strong_wolfe")

    def covs():
        s, ft, fr = torch.exp(theta)
        return s * m + torch.diag(torch.stack([ft, ft, fr]) * cell2)

    def closure():
        opt.zero_grad()
        c = covs()
        loss = ((torch.einsum("pi,pij,pj->p", e, torch.linalg.inv(c), e) + torch.logdet(c)) * w).sum()
        loss.backward()
        return loss

    for _ in range(iterations):
        opt.step(closure)
    s, ft, fr = torch.exp(theta.detach()).tolist()
    shape = CovarianceShape(cov_scale=s, cov_floor_cells=math.sqrt(ft), cov_floor_yaw_cells=math.sqrt(fr),
                            mean_d2=math.nan, pairs=int(len(e)))
    fitted = profile.with_(**shape.profile_fields())
    shape.mean_d2 = float(np.sum(w_np * mahalanobis_sq(e.numpy(), shape_covariances(m.numpy(), fitted),
                                                       covariance_jitter(fitted))))
    return shape


def pair_weights(names: Sequence[str], real_share: float) -> np.ndarray:
    """float[P]: weights giving the pairs of real drives (names starting ``real:``) together
    ``real_share`` of the likelihood and the simulated ones the rest, equal within each group;
    all equal when either group is empty."""
    real = np.array([str(n).startswith(REAL_PREFIX) for n in names])
    if not 0.0 <= real_share <= 1.0:
        raise ValueError(f"real_share must be in [0, 1], got {real_share!r}")
    if real.all() or not real.any():
        return np.full(len(real), 1.0 / max(len(real), 1))
    return np.where(real, real_share / real.sum(), (1.0 - real_share) / (~real).sum())


@torch.no_grad()
def search_estimates(model, drives: Sequence, search: str = "exhaustive", batch: int = 8,
                     progress_desc: str | None = "search estimates", deadline: float | None = None,
                     coverage: dict | None = None):
    """(poses float64[P, 3], moments float64[P, 3, 3], gt float64[P, 3], names) over every
    consecutive pair of ``drives``, as the ``search`` ("exhaustive" | "fast") computes them; the
    moments are the model's covariances with its scale and floor taken back out.

    ``deadline`` (a `time.perf_counter` value): the pairs come in windows of ``batch`` consecutive pairs, taken
    in `spread_order` over every drive while the next window is expected to end by it (at least one window).
    ``coverage`` (a dict) receives ``"estimates": [pairs used, pairs there]``."""
    from radar_odom._progress import progress

    if search not in ("exhaustive", "fast"):
        raise ValueError(f"search must be 'exhaustive' or 'fast', got {search!r}")
    seq = None
    if search == "fast":
        from .fast_search import FastSequenceStep, FastStreamStep

        seq = FastSequenceStep(FastStreamStep(model)).eval()

    def window(images):  # (poses, covariances) of the consecutive pairs of ``images``, as the search has them
        if seq is None:
            return estimate_drive(model, images, batch)
        out = [seq(torch.from_numpy(np.asarray(images[k : k + batch + 1], dtype=np.float32)))
               for k in range(0, len(images) - 1, batch)]
        return torch.cat([o[0] for o in out]).double().numpy(), torch.cat([o[1] for o in out]).double().numpy()

    poses, covs, gts, names = [], [], [], []
    there = sum(d.num_pairs for d in drives)
    if deadline is None:  # every drive whole
        for d in progress(drives, desc=progress_desc, unit="drive", disable=progress_desc is None):
            p, c = window(d.images)
            poses.append(p)
            covs.append(c)
            gts.append(np.asarray(d.poses_rel, np.float64))
            names += [d.name] * len(p)
    else:  # windows of ``batch`` pairs, spread over the drives, while they fit
        wins = [(d, k) for d in drives for k in range(0, d.num_pairs, batch)]
        clock = _Clock(deadline)
        bar = progress(total=len(wins), desc=progress_desc, unit="window", disable=progress_desc is None)
        for i in spread_order(len(wins)):
            if not clock.may_start():
                break
            d, k = wins[i]
            p, c = window(d.images[k : k + batch + 1])
            poses.append(p)
            covs.append(c)
            gts.append(np.asarray(d.poses_rel[k : k + len(p)], np.float64))
            names += [d.name] * len(p)
            bar.update(1)
            clock.done()
        bar.close()
    if coverage is not None:
        coverage["estimates"] = [int(sum(len(p) for p in poses)), there]
    prof = model.profile
    moments = (np.concatenate(covs) - np.diag(prof.covariance_floor)) / prof.cov_scale
    return np.concatenate(poses), moments, np.concatenate(gts), names


def shape_scenario_table(errors: np.ndarray, moments: np.ndarray, names: Sequence[str],
                         before: GridProfile, after: GridProfile) -> str:
    """Markdown: mean / median d² per scenario with the temperature alone and with the fitted shape."""
    d2s = [mahalanobis_sq(errors, shape_covariances(moments, p), covariance_jitter(p)) for p in (before, after)]
    scen = np.array([n.rsplit("-", 1)[0] for n in names])
    lines = ["| scenario | pairs | mean d², temperature only | mean d², fitted | median d², fitted "
             "| mean translation error m |", "|---|---:|---:|---:|---:|---:|"]
    for sc in [*dict.fromkeys(scen), "all"]:
        sel = np.ones(len(scen), bool) if sc == "all" else scen == sc
        lines.append(f"| {sc} | {int(sel.sum())} | {d2s[0][sel].mean():.3g} | {d2s[1][sel].mean():.3g} "
                     f"| {np.median(d2s[1][sel]):.3g} | {np.hypot(*errors[sel, :2].T).mean():.3f} |")
    return "\n".join(lines)


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
                f"β={items[0][0]:.3g} and β={items[-1][0]:.3g}):\n{format_table(items)}", table=items)
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
            f"too few pairs?):\n{format_table(sorted(table.items()))}", table=sorted(table.items()))
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
    covariance: str = "fitted",
    search: str = "exhaustive",
    real_share: float = 1.0,
    work_by: float | None = None,
) -> CalibrationResult:
    """Calibrate a checkpoint's covariance on held-out ``drives``; write it in place or to ``output``.

    ``pose_estimator`` ("soft-argmax" | "parabolic"), if given, is set in the profile first (the
    covariance is calibrated against the errors of the pose the model will report).
    ``covariance``: "temperature" tunes ``beta_cov`` alone (paper Sec. 6.2, the quantisation floor
    kept); "fitted" then fits the per-axis shape (`fit_covariance_shape`) on the estimates of
    ``search`` ("exhaustive" | "fast": the search the model will be exported with). Where
    ``drives`` mix real (named ``real:…``) and simulated drives, the real pairs carry
    ``real_share`` of the shape's likelihood (`pair_weights`).

    ``work_by`` (a `time.perf_counter` value, a budget's end for this work): the correlation volumes take the
    first half of the time left, the search estimates the rest (all of it for the temperature alone), each as
    many pairs, spread over every drive, as fit (`collect_volumes`, `search_estimates`); the result's
    ``coverage`` says how many of how many."""
    from dataclasses import asdict

    from .checkpoint import model_from_dict, read_checkpoint_dict, write_checkpoint_dict

    if covariance not in ("fitted", "temperature"):
        raise ValueError(f"covariance must be 'fitted' or 'temperature', got {covariance!r}")
    ckpt = read_checkpoint_dict(path)
    if pose_estimator:
        ckpt["profile"] = {**ckpt["profile"], "pose_estimator": pose_estimator}
    if covariance == "fitted":  # the temperature is tuned in the paper's form, the shape after it
        ckpt["profile"] = {**ckpt["profile"], "cov_scale": 1.0, "cov_floor_cells": 1.0, "cov_floor_yaw_cells": 1.0}
    model = model_from_dict(ckpt, source=str(path))
    coverage: dict = {}
    volumes_by = work_by
    if work_by is not None and covariance == "fitted":
        # the shape fit's optimiser imports torch._dynamo (seconds on a loaded machine): now, before the
        # stages share out the time left
        torch.optim.LBFGS([torch.zeros(1, requires_grad=True)])
        volumes_by = (time.perf_counter() + work_by) / 2
    volumes, gt, names = collect_volumes(model, drives, batch=batch, max_pairs=max_pairs, with_names=True,
                                         deadline=volumes_by, coverage=coverage)
    curve = D2Curve(volumes, gt, model.candidates, model.profile)
    try:
        result = calibrate_beta(curve, model.profile.beta_pose)
    except CalibrationError as exc:
        if covariance != "fitted" or not exc.table:
            raise
        # the temperature alone cannot bring d̄² into the band on these pairs (a few easy scenarios: their errors
        # sit below the quantisation floor it keeps); the per-axis fit, which sets the scale and the floors by
        # maximum likelihood, still can: the moments are taken at beta_pose
        beta = model.profile.beta_pose
        result = CalibrationResult(beta_cov=beta, mean_d2=curve(beta), table=exc.table, pairs=0)
        result.note = (f"no temperature brings mean d² into {BAND[0]:g}–{BAND[1]:g} on these pairs (the table): "
                       f"beta_cov kept at beta_pose = {beta:g}, the per-axis fit sets the scale")
    result.pairs = int(len(gt))
    result.scenario_table = scenario_d2_table(curve, names, result.beta_cov)
    profile = model.profile.with_(beta_cov=result.beta_cov)
    del volumes, curve
    if covariance == "fitted":
        model = model_from_dict({**ckpt, "profile": asdict(profile)}, source=str(path)).eval()
        poses, moments, gts, pair_names = search_estimates(model, drives, search, batch, deadline=work_by,
                                                           coverage=coverage)
        errors = pose_errors(gts, poses)
        shape = fit_covariance_shape(moments, errors, profile, weights=pair_weights(pair_names, real_share))
        shape.real_share = real_share if any(str(n).startswith(REAL_PREFIX) for n in pair_names) else None
        shape.search = search
        fitted = profile.with_(**shape.profile_fields())
        result.shape, result.mean_d2, result.pairs = shape, shape.mean_d2, shape.pairs
        result.scenario_table = shape_scenario_table(errors, moments, pair_names, profile, fitted)
        profile = fitted
    if work_by is not None:
        result.coverage = coverage
    ckpt["profile"] = asdict(profile)
    ckpt["calibration"] = {
        **result.to_dict(),
        **(info or {}),
        "drives": [d.name for d in drives],
        "per_scenario": result.scenario_table,
    }
    write_checkpoint_dict(output or path, ckpt)
    return result


def is_calibrated(path) -> bool:
    """Whether ``path`` carries a calibration record (`calibrate_checkpoint` writes one; a checkpoint
    straight from `radar-odom train` has none)."""
    from .checkpoint import read_checkpoint_dict

    return "calibration" in read_checkpoint_dict(path)


def coverage_line(result: CalibrationResult, sim_drives: dict | None, minutes: float, seconds: float) -> str:
    """What a budgeted calibration says: how many drives (and sweeps) and pairs of how many it used, its time."""
    cov = result.coverage
    parts = []
    if sim_drives is not None:
        got, asked = sim_drives["sweeps"]
        parts.append(f"{sim_drives['ready']} of {sim_drives['asked']} drives"
                     + (f" ({got} of {asked} sweeps: cut short)" if got < asked else ""))
    parts.append("the temperature on {} of {} pairs".format(*cov["volumes"]))
    if "estimates" in cov:
        parts.append("the per-axis shape on {} of {}".format(*cov["estimates"]))
    short = (sim_drives is not None and sim_drives["sweeps"][0] < sim_drives["sweeps"][1]) or any(
        u < t for u, t in cov.values())
    return (f"calibration: {', '.join(parts)}, in {seconds / 60:.1f} min"
            + (f": as many as fit in the {minutes:g}-minute budget, spread over every drive" if short
               else f", within the {minutes:g}-minute budget"))


def run_from_args(args) -> CalibrationResult:
    """`radar-odom calibrate`: held-out drives on the checkpoint's grid, then `calibrate_checkpoint`."""
    import sys

    from radar_odom.profiles import GridProfile

    from .checkpoint import read_checkpoint_dict
    from .data import build_drives, check_seed_policy, parse_seeds, sequence_drives, sim_specs
    from .real_pairs import DEFAULT_HOLDOUT, real_runs

    started = getattr(args, "started", None) or time.perf_counter()  # `radar-odom export` sets its own start
    minutes = getattr(args, "minutes", None) or None
    if minutes is not None:  # a finite number of minutes, at most a week, said before any work (ConfigError)
        from radar_odom.budgets import check_budget_minutes

        check_budget_minutes(minutes, getattr(args, "minutes_flag", "--minutes"))
    budget_s = None if minutes is None else 60.0 * minutes
    if args.threads:
        torch.set_num_threads(args.threads)
    profile = GridProfile.from_dict(read_checkpoint_dict(args.checkpoint)["profile"])
    info = {"command": provenance_command(sys.argv[1:])}
    real = [d for p in (getattr(args, "real", None) or [])
            for d in real_runs(p, profile, holdout=getattr(args, "real_holdout", DEFAULT_HOLDOUT))]
    if real:
        info.update(real=[str(p) for p in args.real], real_holdout=args.real_holdout, real_share=args.real_share)
    if args.data:
        drives = [d for p in args.data for d in sequence_drives(p, profile)]
        info["data"] = [str(p) for p in args.data]
    else:
        seeds = parse_seeds(args.sim_seeds)
        check_seed_policy(seeds, "val")
        scenarios = [s for s in args.scenarios.split(",") if s]
        sims: dict = {}
        drives = build_drives(
            profile,
            sim_specs(seeds, scenarios, args.frames),
            args.workers,
            with_labels=False,
            desc="calibration drives",
            deadline=None if budget_s is None else started + CAL_SIM_SHARE * budget_s,
            report=sims,
            cut=True,  # every scenario, each drive cut short to fit, rather than the first scenarios whole
        )
        info.update(sim_seeds=seeds, scenarios=scenarios, frames=args.frames)
        if budget_s is not None:
            info["sim_drives"] = {"ready": sims["ready"], "asked": sims["asked"], "sweeps": sims["sweeps"]}
    drives = drives + real
    result = calibrate_checkpoint(
        args.checkpoint,
        drives,
        output=args.output,
        batch=args.batch,
        max_pairs=args.max_pairs,
        info=info,
        pose_estimator=getattr(args, "pose_estimator", None),
        covariance=getattr(args, "covariance", "fitted"),
        search=getattr(args, "search", "exhaustive"),
        real_share=getattr(args, "real_share", 1.0),
        work_by=None if budget_s is None else started + getattr(args, "work_share", CAL_WORK_SHARE) * budget_s,
    )
    print(format_table(result.table, chosen=result.beta_cov))
    if result.note:
        print(f"note: {result.note}")
    if budget_s is not None:
        print(coverage_line(result, info.get("sim_drives"), minutes, time.perf_counter() - started))
    out = args.output or args.checkpoint
    if result.shape is None:
        print("\nper scenario at the chosen β:\n" + result.scenario_table)
        print(f"\nbeta_cov = {result.beta_cov:.4g} -> mean d² = {result.mean_d2:.3f} over {result.pairs} pairs "
              f"(beta_pose = {profile.beta_pose:g}); written to {out}")
        return result
    sh = result.shape
    pairs = ("every consecutive pair" if "estimates" not in result.coverage
             or result.coverage["estimates"][0] == result.coverage["estimates"][1] else "the pairs above")
    print(f"\nper scenario, {sh.search} search, {pairs}:\n" + result.scenario_table)
    print(f"\nbeta_cov = {result.beta_cov:.4g} (beta_pose = {profile.beta_pose:g}), then by maximum likelihood "
          f"cov_scale = {sh.cov_scale:.4g}, cov_floor_cells = {sh.cov_floor_cells:.4g}, "
          f"cov_floor_yaw_cells = {sh.cov_floor_yaw_cells:.4g} -> mean d² = {sh.mean_d2:.3f} over {sh.pairs} pairs"
          + ("" if sh.real_share is None else
             f" (weighted: the real pairs carry {100 * sh.real_share:.0f} % of the fit; per group above)")
          + f"; written to {out}")
    return result
