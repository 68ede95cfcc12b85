"""Is a sweep usable by a model? Degenerate sweeps and sweep geometry, judged where the model looks.

`sweep_problem` says why a sweep cannot be matched (too few valid rows, partial coverage,
saturated, blank, noise only); `check_sweep_geometry` refuses a sweep the model cannot take
(too short for a Cartesian model's disc, range bins no radar has for it (`implausible_range_bins`),
another geometry for a polar one, azimuths closer than a sweep-form graph draws
(`sweep_form_table_problem`)); `model_region_m`
is the range band a model sees. Pure functions of the sweep and the model's `ModelInfo`: the
odometer, `match_sequence` and the tooling share them. The checks of a sweep's arrays that need no
`RadarScan` (the range bins, a sweep-form model's feeds: `check_sweep_feeds`) live in `radar_odom.sweep_arrays`,
re-exported here.
"""
from __future__ import annotations

import numpy as np

from ..errors import ModelMismatchError
from ..onnx_model import GEOMETRY_KEYS
from ..polar import sampling_azimuths
from ..scan import RadarScan
from ..sweep_arrays import (  # noqa: F401  (re-exported: the range bins' checks live beside the sweep form's)
    MAX_OFFSET_SHARE,
    MAX_RESOLUTION_RATIO,
    MIN_RANGE_OFFSET_M,
    check_cartesian_bins,
    check_sweep_feeds,
    implausible_range_bins,
    sweep_form_fix,
    sweep_form_table_problem,
)

MIN_COVERAGE = 0.75
NOISE_STRUCTURE = 0.2
_MAX_STAT_BINS = 256  # range bins sampled for the statistics (a stride over the model's region)


def azimuth_coverage(scan: RadarScan) -> float:
    """Fraction of the turn (0..1) the sweep's valid azimuth rows cover.

    The nominal spacing ``d`` is the median gap between neighbouring valid azimuths (the turn
    wraps round); a gap wider than 2.5 ``d`` leaves ``gap − d`` of the turn uncovered. A full
    sweep with scattered dropped rows covers 1.0; one that spans half a turn (or whose rows
    over half a turn are invalid) about 0.5.
    """
    az = np.asarray(scan.azimuths_rad, dtype=np.float64)[np.asarray(scan.valid, dtype=bool)]
    if az.size < 2:
        return 0.0
    gaps = np.diff(np.append(az, az[0] + 2.0 * np.pi))
    d = float(np.median(gaps))
    wide = gaps[gaps > 2.5 * d]
    return float(np.clip(1.0 - np.sum(wide - d) / (2.0 * np.pi), 0.0, 1.0))


def _region(num_bins: int, res: float, offset: float, min_range_m: float, max_range_m: float):
    """(bin indices, their ranges) sampled from the bins within [min_range_m, max_range_m]."""
    r = offset + np.arange(num_bins, dtype=np.float64) * res
    sel = np.flatnonzero((r >= min_range_m) & (r <= max_range_m))
    if sel.size > _MAX_STAT_BINS:
        sel = sel[:: int(np.ceil(sel.size / _MAX_STAT_BINS))]
    return sel, r[sel]


def sweep_problem(scan: RadarScan, min_valid_fraction: float = 0.5, *, min_range_m: float = 0.0,
                  max_range_m: float | None = None, min_coverage: float = MIN_COVERAGE) -> str | None:
    """Why a sweep cannot be matched, or None.

    The sweep is judged where the model looks: range bins within ``[min_range_m, max_range_m]``
    (`RadarOdometer` passes the near-range cut ``near_range_m`` and the disc it correlates,
    ``GridProfile.support_radius_m``; default: every bin). Reasons, checked in this order:

    - ``"invalid_rows"``: fewer than ``min_valid_fraction`` of the azimuth rows are valid.
    - ``"partial_coverage"``: the valid rows cover less than ``min_coverage`` of the turn
      (`azimuth_coverage`; a sweep over half a turn matches a full one badly and confidently).
    - ``"saturated"``: more than half of the region (area-weighted: a bin at range r covers an
      area ∝ r of the Cartesian image) is at ≥ 0.95 of full scale.
    - ``"blank"``: fewer than 0.1 % of it (area-weighted) exceed 2/255 (a receiver's noise floor
      alone exceeds that), or the region holds no bin.
    - ``"noise_only"``: no spatial structure. Returns of real scenes are smeared over
      neighbouring azimuths (beam width) and range bins (pulse length), receiver noise is not:
      after removing each range ring's mean, the correlation between neighbouring azimuths and
      between neighbouring range bins is below ``NOISE_STRUCTURE`` (0.2) on both axes (or the
      region is flat). Real Oxford and RADIATE sweeps and simulated ones give 0.58–0.93; noise of
      any distribution (uniform, Gaussian, exponential, dB-scaled) gives |ρ| < 0.01. The test is
      scale-free, so it holds at any gain or noise-floor level (Oxford's median power is 0.03,
      RADIATE's 0.09).

    Statistics use the valid rows on at most 256 range bins of the region (a regular stride):
    the decisions are about large fractions of the sweep, so a subsample decides them as well.
    """
    valid = np.asarray(scan.valid, dtype=bool)
    valid_fraction = float(np.count_nonzero(valid)) / scan.num_azimuths
    if valid_fraction < min_valid_fraction:
        return "invalid_rows"
    if azimuth_coverage(scan) < min_coverage:
        return "partial_coverage"
    hi = np.inf if max_range_m is None else float(max_range_m)
    idx, r = _region(scan.num_bins, float(scan.range_resolution_m), float(scan.range_offset_m),
                     float(min_range_m), hi)
    if idx.size == 0:
        return "blank"
    vrows = slice(None) if valid.all() else np.flatnonzero(valid)
    p = scan.power[vrows][:, idx] if isinstance(vrows, slice) else scan.power[np.ix_(vrows, idx)]
    w = np.maximum(r, 0.5 * float(scan.range_resolution_m))
    w = w / (w.sum() * p.shape[0])
    if float(np.count_nonzero(p >= 0.95, axis=0) @ w) > 0.5:
        return "saturated"
    if float(np.count_nonzero(p > 2.0 / 255.0, axis=0) @ w) < 1e-3:
        return "blank"
    if _structure(scan.power, vrows, p, idx) < NOISE_STRUCTURE:
        return "noise_only"
    return None


def _structure(power: np.ndarray, vrows, p: np.ndarray, idx: np.ndarray) -> float:
    """Largest of the neighbouring-azimuth and neighbouring-bin correlations (ring means removed).

    ``p`` is ``power`` at rows ``vrows`` (a slice or indices) and bins ``idx``.
    """
    d = p - p.mean(axis=0, keepdims=True, dtype=np.float64).astype(p.dtype)
    dd = float(np.vdot(d, d))
    if dd <= 1e-12 * d.size:  # flat: no structure at all
        return 0.0
    rho_az = (float(np.vdot(d[1:], d[:-1])) + float(np.vdot(d[0], d[-1]))) / dd  # azimuth wraps
    nxt = np.minimum(idx + 1, power.shape[1] - 1)
    ok = nxt != idx
    rho_bin = 0.0
    if ok.any():
        cols = nxt[ok]
        q = power[vrows][:, cols] if isinstance(vrows, slice) else power[np.ix_(vrows, cols)]
        q = q - q.mean(axis=0, keepdims=True, dtype=np.float64).astype(q.dtype)
        a = d if ok.all() else np.ascontiguousarray(d[:, ok])
        den = float(np.sqrt(float(np.vdot(a, a)) * float(np.vdot(q, q))))
        rho_bin = float(np.vdot(a, q)) / den if den > 0 else 0.0
    return max(rho_az, rho_bin)


def model_region_m(info) -> tuple[float, float]:
    """(near, far) ranges (m) of the sweep a model sees: from the near-range cut to the disc it
    correlates (Cartesian models: ``support_radius_m``), or to the last bin a polar model reads."""
    p = info.profile
    if p.input_kind != "polar":
        return float(p.near_range_m), float(p.support_radius_m)
    geom, spec = info.sweep_geometry, info.polar_input or {}
    nb = int(spec.get("num_bins", geom["num_bins"])) * int(spec.get("bin_factor", 1))
    return float(p.near_range_m), float(geom["range_offset_m"]) + nb * float(geom["range_resolution_m"])


def check_sweep_geometry(scan: RadarScan, info, model_name: str = "the model") -> None:
    """`ModelMismatchError` unless the model described by ``info`` (a `ModelInfo`) can take
    ``scan`` (see the module docstring); ``model_name`` is used in the message. A sweep-form model
    also needs azimuths its bearing table can draw (`sweep_form_table_problem`)."""
    if info.profile.input_kind != "polar":
        check_cartesian_bins(scan.source, scan.num_bins, float(scan.range_resolution_m), float(scan.range_offset_m),
                              info, model_name)
        if info.form == "sweep":
            why = sweep_form_table_problem(sampling_azimuths(scan))  # the azimuths the graph is fed
            if why is not None:
                raise ModelMismatchError(f"{scan.source}: {why}; {sweep_form_fix(info, model_name)}")
        return
    want = info.sweep_geometry
    got = scan.geometry
    bad = [
        k for k in GEOMETRY_KEYS
        if not np.isclose(float(got[k]), float(want[k]), rtol=1e-6, atol=1e-9)
    ]
    if bad:
        raise ModelMismatchError(
            f"{scan.source}: sweep geometry {{{', '.join(f'{k}: {got[k]}' for k in bad)}}} differs from "
            f"model {model_name} ({', '.join(f'{k}: {want[k]}' for k in bad)}); use a model trained "
            "for this radar, or resample the sweep to the model's geometry"
        )
