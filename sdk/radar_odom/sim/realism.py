"""Sweep statistics that say whether simulated sweeps look like a real radar's.

Every statistic is computed on the polar power image float[A, B] in [0, 1] as `load_scan`
returns it (Navtech 8-bit log power / 255), over the valid azimuth rows, and averaged over the
sweeps given. They are chosen to cover what a matcher and a masker see:

* ``q50 … q99.9``: intensity quantiles (the noise floor and the strong returns);
* ``share>L``: fraction of cells above fixed levels L (how much of a sweep is bright);
* ``mean r0–r1 m``: mean power in range bands (range fall-off and near-range clutter);
* ``azimuth variation``: std / mean of the per-azimuth mean power (real heads show strong
  azimuth-to-azimuth gain changes: streaks, occlusion, beam squint);
* ``range corr. length`` / ``azimuth corr. length``: the lag (in cells, linearly interpolated)
  where the autocorrelation of the power, with each row's (column's) mean removed, first falls
  below 1/2 — the speckle and point-spread size along range and along azimuth.

`compare` puts real and simulated statistics side by side with their ratio.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

QUANTILES = (0.5, 0.9, 0.99, 0.999)
LEVELS = (0.1, 0.2, 0.3)
RANGE_BANDS_M = ((0.0, 13.0), (13.0, 43.0), (43.0, 86.0), (86.0, 163.0))
MAX_LAG = 64


def _corr_length(x: np.ndarray, axis: int, circular: bool) -> float:
    """Lag (cells) where the autocorrelation of ``x`` along ``axis`` first drops below 1/2."""
    x = np.moveaxis(x, axis, 0).astype(np.float64)
    var = float(np.mean(x * x))
    if var <= 0:
        return 0.0
    prev = 1.0
    n = x.shape[0]
    for lag in range(1, min(MAX_LAG, n - 1) + 1):
        if circular:
            c = float(np.mean(x * np.roll(x, -lag, axis=0))) / var
        else:
            a, b = x[:-lag], x[lag:]
            c = float(np.mean(a * b)) / np.sqrt(float(np.mean(a * a)) * float(np.mean(b * b)) + 1e-30)
        if c < 0.5:
            return lag - 1 + (prev - 0.5) / max(prev - c, 1e-12)
        prev = c
    return float(MAX_LAG)


def sweep_statistics(power: np.ndarray, range_resolution_m: float, valid: np.ndarray | None = None,
                     range_offset_m: float = 0.0) -> dict[str, float]:
    """The statistics of one sweep (see the module docstring), as an ordered dict name → value.

    Args:
        power: float[A, B] in [0, 1], rows = azimuths, columns = range bins.
        range_resolution_m, range_offset_m: bin b's centre lies at ``offset + (b + 0.5)·res``.
        valid: bool[A] rows to use (default all).
    """
    p = np.asarray(power, dtype=np.float32)
    if valid is not None:
        p = p[np.asarray(valid, dtype=bool)]
    out: dict[str, float] = {}
    flat = p.ravel()
    for q, v in zip(QUANTILES, np.quantile(flat, QUANTILES)):
        out[f"q{q * 100:g}"] = float(v)
    for lev in LEVELS:
        out[f"share>{lev:g}"] = float(np.count_nonzero(flat > lev)) / flat.size
    r = range_offset_m + (np.arange(p.shape[1]) + 0.5) * range_resolution_m
    for r0, r1 in RANGE_BANDS_M:
        sel = (r >= r0) & (r < r1)
        if sel.any():
            out[f"mean {r0:g}-{r1:g} m"] = float(p[:, sel].mean())
    az_mean = p.mean(axis=1)
    out["azimuth variation"] = float(az_mean.std() / max(float(az_mean.mean()), 1e-12))
    out["range corr. length"] = _corr_length(p - p.mean(axis=1, keepdims=True), axis=1, circular=False)
    out["azimuth corr. length"] = _corr_length(p - p.mean(axis=0, keepdims=True), axis=0, circular=True)
    return out


def mean_statistics(scans: Iterable) -> dict[str, float]:
    """Statistics averaged over `RadarScan` objects (keys present in every sweep)."""
    rows = [sweep_statistics(s.power, s.range_resolution_m, s.valid, s.range_offset_m) for s in scans]
    if not rows:
        raise ValueError("no sweeps given")
    keys = [k for k in rows[0] if all(k in r for r in rows)]
    return {k: float(np.mean([r[k] for r in rows])) for k in keys}


def compare(
    real: dict[str, float], sim: dict[str, float], tolerance: float = 0.3
) -> list[tuple[str, float, float, float, bool]]:
    """Rows ``(name, real, sim, sim/real, within tolerance)`` for the statistics both hold."""
    out = []
    for k in real:
        if k not in sim:
            continue
        ratio = sim[k] / real[k] if real[k] else float("inf")
        out.append((k, real[k], sim[k], ratio, abs(ratio - 1.0) <= tolerance))
    return out


def format_table(rows: Sequence[tuple], names: tuple[str, str] = ("real", "simulated")) -> str:
    """Markdown table of `compare` rows."""
    lines = [f"| statistic | {names[0]} | {names[1]} | ratio | within ±30 % |", "|---|---:|---:|---:|:---:|"]
    for k, a, b, ratio, ok in rows:
        fmt = (lambda v: f"{v * 100:.3f} %") if k.startswith("share") else (lambda v: f"{v:.4g}")
        lines.append(f"| {k} | {fmt(a)} | {fmt(b)} | {ratio:.2f} | {'yes' if ok else 'no'} |")
    return "\n".join(lines)
