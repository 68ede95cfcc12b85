"""Post-graph covariance correction (numpy only): an honest 3×3 covariance in every kind of scene.

The graph's covariance is ``Σ = M + F``: ``M`` the second moment of the ``beta_cov`` soft-argmax
over the correlation volume (paper eq. 3) and ``F = diag(c²/12 · cell²)`` the quantisation floor
the graph adds (``GridProfile.covariance_floor``, ``c = cov_floor_cells``; cell = ``resolution_m``
for x and y, ``rotation_step_rad`` for yaw). One temperature cannot make both right:

- where matching works (urban, heavy traffic) ``M`` is almost zero and ``Σ ≈ F``; the parabolic
  pose read-out is accurate to a small fraction of a cell there, so ``F`` alone is too wide in
  y and yaw and mean d² is ≈ 0.4 (conservative);
- where it fails (a corridor on ``open`` / ``highway`` roads) ``M`` is a ridge along x of a few
  cells², while the error along it is a few cells whatever the ridge's width (the soft-argmax
  cannot see how far the ridge really goes): mean d² 5–10 (overconfident).

Measured on the shipped models (simulated drives): ``M`` is essentially rank one (x, or x with
some yaw); the error along its principal direction is about a tenth of a cell while the moment is
below ~0.03 cells² and several cells once it exceeds ~0.3 cells² (a ridge: the soft-argmax cannot
see how far it really goes, and the read-out collapses towards zero forward motion). Those
corridor errors are *biased and correlated from sweep to sweep*, so a motion prior that fuses
them as independent noise drifts with them: the ridge direction is best reported as unknown.
The correction works in *cell units* (``D = diag(cell)``; the eigen-decomposition of a matrix
mixing m² and rad² would depend on the units chosen), on ``D⁻¹ M D⁻¹ = V diag(λ) Vᵀ``:

    Σ' = D ( diag(floor · (1 + floor_growth · λ₁)) + V diag(min(scale · λ^power, max_moment)) Vᵀ ) D

- ``floor`` (cells², per axis x, y, yaw) replaces the graph's floor ``F``: the variance of the
  read-out's error when the volume is sharply peaked (its sub-cell accuracy, per axis: the
  shipped models read y to ~0.05 cell, x to ~0.1, yaw to ~0.2 of a step — not the graph's
  uniform 0.29).
- ``scale · λ^power`` with ``power`` = 3 (`DEFAULT_POWER`) acts as a soft switch: a moment of
  0.05 cells² stays about a tenth of a cell², one of 0.3 cells² becomes tens of cells², a wider
  ridge "unknown" (bounded by ``max_moment``, `window_moment_cap`, for the sake of conditioning).
  With the motion prior on, that direction is then carried by the prediction.
- ``floor_growth`` (optional, 0 by default) lets the floor grow with the ridge (the yaw error
  also grows with it); tried, not needed by the shipped models.

The identity parameters (``floor = graph_floor``, ``scale = 1``, ``power = 1``, no cap, no
growth) give the input back. The function is pure numpy, batched, and cheap (one 3×3 ``eigh``
per covariance); the parameters (`CovarianceCorrection`) are a small JSON-able dataclass, fitted
on calibration drives by `fit_correction` (numpy only: Nelder–Mead over the 3 floors and the
scale; the objective asks for mean d² ≈ 3 in every scenario *and* a marginal d² ≈ 1 on every
axis, so no axis can be given up to make the total right).

What it cannot do: a *confidently wrong* match (a false peak as sharp as a true one, e.g. a
zero-motion peak on an open road, or a yaw at the edge of the search window) has a small moment
and keeps a small covariance. Mean d² is dominated by such steps (3–6 % of steps have d² above
χ²₃'s 99.9 % point, against 0.1 % for a Gaussian), so mean d² per scenario over two drives is a
noisy figure: fitted on sim seeds 2500-2501, the shipped models meet the bands on held-out seeds
5000-5001 but not on 5002-5003 (nor does the uncorrected graph). Judge a fit on more drives.

Where to apply: in `RadarOdometer._run_pair`, on the graph's covariance as it comes out
(before a bridged match adds the window covariance and before the motion prior fuses it), so
``Estimate.measurement_covariance``, the gate and the fusion weights all see the corrected one.
The parameters belong with the model (they depend on its grid and its training): stored in the
ONNX metadata as `CovarianceCorrection.to_json`, read with `CovarianceCorrection.from_json`,
checked against the profile with `CovarianceCorrection.matches`; a model without them runs
with the identity.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

KIND = "eigen-power-floor/1"
#: the power `fit_correction` uses unless told to fit it (module docstring)
DEFAULT_POWER = 3.0
#: `window_moment_cap` in search-window variances
CAP_WINDOWS = 100.0
#: jitter (in cells) added to the diagonal before inverting, as `radar_odom.metrics` does for d²
_JITTER_CELLS = 1e-3


def window_moment_cap(translation_cells: int, windows: float = CAP_WINDOWS) -> float:
    """cells²: ``windows`` × the variance of a uniform pose over a ``±translation_cells`` window.

    The default 100 windows is σ ≈ 50 m on both shipped grids (±10 cells of 0.8 m, ±20 of
    0.4 m): "unknown" to any filter, yet a 3×3 covariance whose condition number stays below
    ~1e9, so that inverses with a relative eigenvalue floor (`radar_odom.motion_prior.inv_psd`:
    1e-12 of the largest) leave the well-known axes alone. Uncapped, a cubed ridge of 30 cells²
    reaches 1e7 m² and a condition number of 1e12, where that floor inflates the yaw variance.
    """
    return float(windows) * float(translation_cells) ** 2 / 3.0


def _triple(value, name: str, positive: bool = True) -> tuple[float, float, float]:
    try:
        t = tuple(float(v) for v in value)
    except TypeError:
        raise ValueError(f"{name} must be three numbers (x, y, yaw), got {value!r}") from None
    if len(t) != 3 or not all(math.isfinite(v) for v in t):
        raise ValueError(f"{name} must be three finite numbers (x, y, yaw), got {value!r}")
    if positive and min(t) <= 0:
        raise ValueError(f"{name} must be positive, got {value!r}")
    if not positive and min(t) < 0:
        raise ValueError(f"{name} must be non-negative, got {value!r}")
    return t


@dataclass(frozen=True)
class CovarianceCorrection:
    """Parameters of `correct_covariance` (module docstring); JSON via `to_json` / `from_json`.

    Attributes:
        cell: (m, m, rad) the grid's cell per axis: ``(resolution_m, resolution_m,
            rotation_step_rad)`` of the model's profile. All other numbers are in these units.
        graph_floor: (cells², cells², cells²) the floor the graph already added to its
            covariance, ``cov_floor_cells² / 12`` per axis (``GridProfile.covariance_floor``
            divided by ``cell²``); it is taken off before the moment is corrected.
        floor: (cells², cells², cells²) the floor added instead (x, y, yaw).
        scale: multiplies the soft-argmax moment's eigenvalues raised to ``power``, > 0.
        power: exponent on the moment's eigenvalues in cells², > 0 (1: unchanged).
        max_moment: cells², upper bound on each corrected eigenvalue ``scale · λ^power`` (None:
            none); `window_moment_cap` gives the one used for the shipped models (100 times the
            variance of a uniform pose over the search window: "unknown", yet well conditioned).
            Bounding at one window variance was tried: a corridor's biased match then keeps
            enough weight to drag the motion prior along (fused d² on highway 5 → 10).
        floor_growth: (per cell², per axis) the floor grows with the moment's largest eigenvalue
            ``λ₁`` (cells²): ``floor_i · (1 + floor_growth_i · λ₁)``. A volume that is not sharply
            peaked along one direction (a ridge) also reads the other axes less precisely (the
            yaw error grows with the ridge's width). (0, 0, 0): a constant floor.
        kind: format tag (`KIND`).
        fitted_on: free-form provenance (drives, model), not used by the maths.
    """

    cell: tuple[float, float, float]
    graph_floor: tuple[float, float, float] = (1.0 / 12.0, 1.0 / 12.0, 1.0 / 12.0)
    floor: tuple[float, float, float] = (1.0 / 12.0, 1.0 / 12.0, 1.0 / 12.0)
    scale: float = 1.0
    power: float = 1.0
    max_moment: float | None = None
    floor_growth: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kind: str = KIND
    fitted_on: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "cell", _triple(self.cell, "cell"))
        object.__setattr__(self, "graph_floor", _triple(self.graph_floor, "graph_floor", positive=False))
        object.__setattr__(self, "floor", _triple(self.floor, "floor", positive=False))
        object.__setattr__(self, "floor_growth", _triple(self.floor_growth, "floor_growth", positive=False))
        for name in ("scale", "power"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"CovarianceCorrection.{name} must be a positive number, got {v!r}")
            object.__setattr__(self, name, v)
        if self.max_moment is not None:
            v = float(self.max_moment)
            if not (v > 0):  # also NaN
                raise ValueError(f"CovarianceCorrection.max_moment must be a positive number or None, got {v!r}")
            object.__setattr__(self, "max_moment", v)
        if self.kind != KIND:
            raise ValueError(f"unknown covariance correction kind {self.kind!r} (this runtime reads {KIND!r})")
        object.__setattr__(self, "fitted_on", dict(self.fitted_on or {}))

    # --- construction -----------------------------------------------------------------------
    @classmethod
    def identity(cls, cell, graph_floor=(1.0 / 12.0,) * 3) -> CovarianceCorrection:
        """Parameters that give every covariance back unchanged."""
        return cls(cell=cell, graph_floor=graph_floor, floor=graph_floor, scale=1.0, power=1.0)

    @staticmethod
    def profile_units(profile) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(cell, graph_floor) of a `GridProfile` (anything with ``resolution_m``,
        ``rotation_step_rad`` and ``cov_floor_cells``)."""
        cell = (float(profile.resolution_m), float(profile.resolution_m), float(profile.rotation_step_rad))
        f = float(getattr(profile, "cov_floor_cells", 0.0)) ** 2 / 12.0
        return cell, (f, f, f)

    @classmethod
    def identity_for(cls, profile) -> CovarianceCorrection:
        """`identity` in the units of ``profile`` (a `GridProfile`)."""
        return cls.identity(*cls.profile_units(profile))

    def matches(self, profile, rtol: float = 1e-6) -> bool:
        """Whether these parameters were made for ``profile``'s grid and graph floor."""
        cell, gf = self.profile_units(profile)
        return bool(np.allclose(cell, self.cell, rtol=rtol)
                    and np.allclose(gf, self.graph_floor, rtol=rtol, atol=1e-12))

    # --- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("cell", "graph_floor", "floor", "floor_growth"):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> CovarianceCorrection:
        known = {"cell", "graph_floor", "floor", "scale", "power", "max_moment", "floor_growth", "kind",
                 "fitted_on"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown covariance correction field(s): {sorted(unknown)}")
        if "cell" not in d:
            raise ValueError("a covariance correction needs 'cell'")
        return cls(**d)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> CovarianceCorrection:
        return cls.from_dict(json.loads(text))

    @property
    def is_identity(self) -> bool:
        return (self.scale == 1.0 and self.power == 1.0 and self.floor == self.graph_floor
                and self.max_moment is None and not any(self.floor_growth))


# --------------------------------------------------------------------------- the correction
def _sym(c: np.ndarray) -> np.ndarray:
    return 0.5 * (c + np.swapaxes(c, -1, -2))


def moment_eigen(cov, params: CovarianceCorrection) -> tuple[np.ndarray, np.ndarray]:
    """(λ float64[..., 3] ≥ 0 ascending, V float64[..., 3, 3]): eigen-decomposition of the graph's
    soft-argmax moment in cell units, ``D⁻¹ (Σ − F) D⁻¹`` (negative round-off clipped to 0)."""
    c = np.asarray(cov, dtype=np.float64)
    if c.shape[-2:] != (3, 3):
        raise ValueError(f"cov must have shape [..., 3, 3], got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("cov holds NaN/inf")
    d = np.asarray(params.cell)
    m = _sym(c) / d[:, None] / d[None, :] - np.diag(params.graph_floor)
    lam, v = np.linalg.eigh(m)
    return np.maximum(lam, 0.0), v


def corrected_from_eigen(lam: np.ndarray, v: np.ndarray, params: CovarianceCorrection,
                         in_cells: bool = False) -> np.ndarray:
    """Σ' from a `moment_eigen` decomposition (in cells² with ``in_cells``, else m²/rad²)."""
    # the graph computes in float32: moments below (1e-3 cell)² are round-off (which a power < 1
    # would blow up); taking that much off every eigenvalue keeps the map continuous
    lam_p = params.scale * np.power(np.maximum(lam - _JITTER_CELLS**2, 0.0), params.power)
    if params.max_moment is not None:
        lam_p = np.minimum(lam_p, params.max_moment)
    floor = np.asarray(params.floor) * (1.0 + np.asarray(params.floor_growth) * lam[..., -1:])
    out = np.einsum("...ik,...k,...jk->...ij", v, lam_p, v) + floor[..., :, None] * np.eye(3)
    if not in_cells:
        d = np.asarray(params.cell)
        out = out * d[:, None] * d[None, :]
    return _sym(out)


def correct_covariance(cov, params: CovarianceCorrection) -> np.ndarray:
    """The corrected covariance (module docstring) of one graph covariance or a batch.

    Args:
        cov: float[3, 3] or float[..., 3, 3] covariance over (x m, y m, yaw rad) as the graph
            gives it (the ``beta_cov`` soft-argmax moment plus the graph's floor).
        params: `CovarianceCorrection` for the model's grid.
    Returns:
        float64 of the same shape, symmetric positive definite when every ``floor`` entry is
        positive (positive semi-definite otherwise), in the same units. The identity parameters
        return ``cov`` (symmetrised) up to round-off.
    """
    if params.is_identity:
        return _sym(np.asarray(cov, dtype=np.float64))
    lam, v = moment_eigen(cov, params)
    return corrected_from_eigen(lam, v, params)


# --------------------------------------------------------------------------- d² and the fit
def mahalanobis_sq_cells(err_cells: np.ndarray, cov_cells: np.ndarray) -> np.ndarray:
    """float64[N]: ``eᵀ (Σ + jitter)⁻¹ e`` for errors [N, 3] and covariances [N, 3, 3] both in
    cell units (the same d² as in metres and radians: d² does not depend on the units)."""
    c = cov_cells + np.eye(3) * _JITTER_CELLS**2
    sol = np.linalg.solve(c, err_cells[..., None])[..., 0]
    return np.einsum("ni,ni->n", err_cells, sol)


def group_mean_d2(d2: np.ndarray, groups: np.ndarray) -> dict:
    """{group: mean d²} in first-seen order."""
    groups = np.asarray(groups)
    return {g: float(d2[groups == g].mean()) for g in dict.fromkeys(groups.tolist())}


def _nelder_mead(f: Callable[[np.ndarray], float], x0: np.ndarray, step: float = 0.5,
                 iters: int = 600, tol: float = 1e-7) -> np.ndarray:
    """Minimise ``f`` from ``x0`` (standard Nelder–Mead; restarted once from the best point)."""
    x0 = np.asarray(x0, dtype=np.float64)
    best = x0
    for _ in range(2):
        n = len(best)
        simplex = [best] + [best + step * np.eye(n)[i] for i in range(n)]
        vals = [f(x) for x in simplex]
        for _ in range(iters):
            order = np.argsort(vals)
            simplex = [simplex[i] for i in order]
            vals = [vals[i] for i in order]
            if abs(vals[-1] - vals[0]) <= tol * (abs(vals[0]) + tol):
                break
            centroid = np.mean(simplex[:-1], axis=0)
            xr = centroid + (centroid - simplex[-1])
            fr = f(xr)
            if fr < vals[0]:
                xe = centroid + 2.0 * (centroid - simplex[-1])
                fe = f(xe)
                simplex[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
            elif fr < vals[-2]:
                simplex[-1], vals[-1] = xr, fr
            else:
                xc = centroid + 0.5 * (simplex[-1] - centroid)
                fc = f(xc)
                if fc < vals[-1]:
                    simplex[-1], vals[-1] = xc, fc
                else:  # shrink towards the best
                    simplex = [simplex[0]] + [simplex[0] + 0.5 * (x - simplex[0]) for x in simplex[1:]]
                    vals = [vals[0]] + [f(x) for x in simplex[1:]]
        best = simplex[int(np.argmin(vals))]
        step *= 0.25
    return best


def fit_correction(covs, errors, groups: Sequence, cell, graph_floor=(1.0 / 12.0,) * 3, target: float = 3.0,
                   fit: Sequence[str] = ("floor", "scale"), init: CovarianceCorrection | None = None,
                   fitted_on: dict | None = None, axis_weight: float = 1.0,
                   max_moment: float | None = None, max_power: float = 3.0) -> tuple[CovarianceCorrection, dict]:
    """Fit `CovarianceCorrection` so that mean d² ≈ ``target`` in every group (numpy only).

    Args:
        covs: float[N, 3, 3] graph covariances (x m, y m, yaw rad) on calibration drives.
        errors: float[N, 3] pose errors ``gt − estimate`` (yaw wrapped to (−π, π]).
        groups: N labels (e.g. scenario names); every group is meant to be honest on its own.
        cell, graph_floor: the model's units (`CovarianceCorrection.profile_units`).
        target: the mean d² aimed at in each group (3 for 3 DOF).
        max_moment: the bound on corrected moment eigenvalues, cells² (fixed, not fitted;
            e.g. the search window's ``translation_cells² / 3``); scaled with the rest by the
            final factor.
        max_power: the power is kept within [0.05, max_power] (3: a ridge twice as wide is
            8× less known; steeper is a switch, and fits calibration noise).
        fit: which parameters are free (any of ``"floor"``, ``"scale"``, ``"power"``,
            ``"growth"``: ``floor_growth``); the others keep ``init``'s values. Default: the
            floor and the scale, from ``init`` = the graph's floor, scale 10, power
            `DEFAULT_POWER` (pass ``init=CovarianceCorrection.identity(...)`` to start from
            the graph as it is).
        axis_weight: weight of the per-axis terms of the objective (0: mean d² alone).
    Objective: ``Σ_g log(mean d²_g / target)²`` over the groups (each group counts once,
    whatever its size) plus ``axis_weight · Σ_g Σ_axis log(mean z²_g,axis · target/3)²`` with
    ``z² = e_axis² / Σ'_axis,axis`` each axis's marginal d² (ideal mean 1). Mean d² alone can be
    met dishonestly — a huge variance on one axis (its d² share → 0) and too small ones on the
    others — the per-axis terms rule that out. Minimised by Nelder–Mead over log floor, log
    scale and power.
    Afterwards every covariance is scaled by one factor (floor, scale, max_moment) so that the
    mean d² over all N is exactly ``target`` (d² scales as 1 / that factor).

    Returns:
        (parameters, report) with report ``{"before", "after": {group: mean d²}, "mix_before",
        "mix_after", "objective"}`` ("before": the graph's covariance as it is).
    """
    covs = np.asarray(covs, dtype=np.float64)
    err = np.asarray(errors, dtype=np.float64).copy()
    err[:, 2] = -((-err[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    groups = np.asarray(groups)
    if covs.shape != (len(err), 3, 3) or len(groups) != len(err):
        raise ValueError(f"covs [N, 3, 3], errors [N, 3] and groups [N] must match, got "
                         f"{covs.shape}, {err.shape}, {groups.shape}")
    if init is None:  # the shipped recipe: floor and scale fitted, cubic power
        init = CovarianceCorrection(cell=cell, graph_floor=graph_floor, floor=graph_floor, scale=10.0,
                                    power=DEFAULT_POWER)
    base = init
    base = CovarianceCorrection(cell=cell, graph_floor=graph_floor, floor=base.floor, scale=base.scale,
                                power=base.power, max_moment=max_moment, floor_growth=base.floor_growth)
    d = np.asarray(base.cell)
    ec = err / d
    lam, v = moment_eigen(covs, base)
    names = list(dict.fromkeys(groups.tolist()))
    masks = [groups == g for g in names]

    def unpack(x) -> CovarianceCorrection:
        i, kw = 0, {}
        if "floor" in fit:
            kw["floor"] = tuple(float(np.exp(t)) for t in x[i:i + 3])
            i += 3
        if "scale" in fit:
            kw["scale"] = float(np.exp(x[i]))
            i += 1
        if "power" in fit:
            kw["power"] = float(np.clip(x[i], 0.05, max_power))
            i += 1
        if "growth" in fit:
            kw["floor_growth"] = tuple(float(np.exp(t)) for t in x[i:i + 3])
        return CovarianceCorrection(cell=base.cell, graph_floor=base.graph_floor, max_moment=base.max_moment,
                                    **{**{"floor": base.floor, "scale": base.scale, "power": base.power,
                                       "floor_growth": base.floor_growth}, **kw})

    def d2_of(p: CovarianceCorrection) -> np.ndarray:
        return mahalanobis_sq_cells(ec, corrected_from_eigen(lam, v, p, in_cells=True))

    def score(p: CovarianceCorrection) -> float:
        cc = corrected_from_eigen(lam, v, p, in_cells=True)
        d2 = mahalanobis_sq_cells(ec, cc)
        total = sum(np.log(d2[m].mean() / target) ** 2 for m in masks)
        if axis_weight:
            z2 = ec**2 / np.diagonal(cc, axis1=1, axis2=2)  # each axis's own (marginal) d², ideal mean 1
            total += axis_weight * sum(np.sum(np.log(z2[m].mean(axis=0) * target / 3.0) ** 2) for m in masks)
        return float(total)

    def objective(x) -> float:
        return score(unpack(x))

    x0 = []
    if "floor" in fit:
        x0 += [math.log(max(f, 1e-6)) for f in base.floor]
    if "scale" in fit:
        x0.append(math.log(base.scale))
    if "power" in fit:
        x0.append(base.power)
    if "growth" in fit:
        x0 += [math.log(max(g, 1e-2)) for g in base.floor_growth]
    x = _nelder_mead(objective, np.array(x0)) if x0 else np.zeros(0)
    p = unpack(x)
    # one overall factor so the mean over all pairs is the target exactly
    k = float(d2_of(p).mean() / target)
    p = CovarianceCorrection(cell=p.cell, graph_floor=p.graph_floor, floor=tuple(k * f for f in p.floor),
                             scale=p.scale * k, power=p.power,
                             max_moment=None if p.max_moment is None else p.max_moment * k,
                             floor_growth=p.floor_growth,
                             fitted_on=fitted_on or {})
    ident = CovarianceCorrection.identity(base.cell, base.graph_floor)
    before = mahalanobis_sq_cells(ec, corrected_from_eigen(lam, v, ident, in_cells=True))
    after = d2_of(p)
    return p, {"before": group_mean_d2(before, groups), "after": group_mean_d2(after, groups),
               "mix_before": float(before.mean()), "mix_after": float(after.mean()),
               "objective": score(p)}
