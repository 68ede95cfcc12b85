"""A sweep's arrays checked as the SDK checks a sweep, where no `RadarScan` is: the range bins a Cartesian model can
take (`implausible_range_bins`, `check_cartesian_bins`) and a sweep-form model's feeds built by hand
(`check_sweep_feeds`: `OnnxModel.run`, `OpenVinoModel.run` and `sweep_feeds` call it), with the errors the SDK path
raises for the same faults (`RadarScan.from_arrays`'s `ScanFormatError`, `check_sweep_geometry`'s
`ModelMismatchError`), and what the sweep form's bearing table can draw (`sweep_form_table_problem`).
Shared vocabulary: `radar_odom.odometry.sweep_checks` re-exports these and checks `RadarScan`s with them."""
from __future__ import annotations

import numpy as np

from .errors import ModelMismatchError, ScanFormatError
from .model_file import SWEEP_INPUTS, SWEEP_TABLE_BINS

# a sweep's range bins may be this many times finer or coarser than those the model was trained on, no more: real
# radars span 4x (Oxford 0.0432 m, RADIATE 0.1736 m), a wrong --range-resolution-m is typically 10x or more off
MAX_RESOLUTION_RATIO = 8.0
# the range of a sweep's column 0 is a calibration of decimetres (Boreas −0.31 m); below this it is a wrong setting
MIN_RANGE_OFFSET_M = -5.0
MAX_OFFSET_SHARE = 0.5  # a sweep starting beyond half the correlated disc's radius leaves 3/4 of its area empty


def implausible_range_bins(range_resolution_m: float, range_offset_m: float, info) -> str | None:
    """Why range bins of ``range_resolution_m`` (m per bin) from ``range_offset_m`` (m, the range of column 0)
    cannot be a radar's for the Cartesian model ``info`` (a `ModelInfo`), or None: a resolution more than
    `MAX_RESOLUTION_RATIO` times finer or coarser than the model's sweeps' (its ``sweep_geometry``, where it
    has one), an offset below `MIN_RANGE_OFFSET_M` (ranges below zero), or one beyond `MAX_OFFSET_SHARE` of
    the radius of the disc the model correlates (``support_radius_m``: most of its area would be missing).
    The reach (the disc beyond the last bin) is `check_sweep_geometry`'s own test."""
    p = info.profile
    want = (info.sweep_geometry or {}).get("range_resolution_m")
    if want:
        ratio = float(range_resolution_m) / float(want)
        if not 1.0 / MAX_RESOLUTION_RATIO <= ratio <= MAX_RESOLUTION_RATIO:
            return (f"range bins of {range_resolution_m:g} m are {ratio:.3g}x the {float(want):g} m of the sweeps the "
                    f"model was made for (at most {MAX_RESOLUTION_RATIO:g}x either way: Oxford 0.0432 m, RADIATE "
                    "0.1736 m)")
    if range_offset_m < MIN_RANGE_OFFSET_M:
        return (f"column 0 lies at {range_offset_m:g} m, below {MIN_RANGE_OFFSET_M:g} m (a radar's first bin is "
                "within decimetres of its antenna: Boreas −0.31 m)")
    if range_offset_m >= MAX_OFFSET_SHARE * float(p.support_radius_m):
        return (f"column 0 lies at {range_offset_m:g} m, beyond half the radius of the disc the model correlates "
                f"({float(p.support_radius_m):.2f} m): most of the disc would be missing")
    return None


def check_cartesian_bins(source: str, num_bins: int, res: float, offset: float, info, model_name: str) -> None:
    """`ModelMismatchError` where ``num_bins`` range bins of ``res`` m from ``offset`` m cannot feed the Cartesian
    model ``info``: bins no radar has for it (`implausible_range_bins`), or a sweep too short for its disc."""
    why = implausible_range_bins(res, offset, info)
    if why is not None:
        raise ModelMismatchError(
            f"{source}: {why}; check the range resolution and offset the sweep was read with "
            "(--range-resolution-m / --range-offset-m for a bag, range_resolution_m= / range_offset_m= in "
            "RadarScan.from_arrays or load_scan)")
    need = info.profile.support_radius_m
    have = offset + num_bins * res
    if have < need - 1e-6:
        p = info.profile
        raise ModelMismatchError(
            f"{source}: the sweep reaches {have:.2f} m ({num_bins} bins of "
            f"{res:g} m), but model {model_name} correlates a disc of "
            f"radius {need:.2f} m ({p.width_px} px at {p.resolution_m:g} m/px less the "
            f"±{p.translation_cells}-cell search window); use a model with a smaller grid "
            f"(width_px × resolution_m) or sweeps that reach at least {need:.2f} m"
        )


def sweep_form_table_problem(azimuths_rad) -> str | None:
    """Why a sweep-form graph (docs/sweep-form.md) cannot draw a sweep with these azimuths (rad, increasing, in
    [0, 2π)) as the SDK draws it, or None. The graph finds each pixel's row through a table of `SWEEP_TABLE_BINS`
    equal bearing bins, exact only where no bin holds two azimuths; computed in float32 as the graph computes it.
    Closer rows (4000 azimuths: 0.09° apart) put pixels on the wrong rows: poses centimetres from the SDK's."""
    az = np.asarray(azimuths_rad, dtype=np.float32).reshape(-1)
    per_rad = np.float32(SWEEP_TABLE_BINS / (2.0 * np.pi))
    bins = np.minimum(np.floor(az * per_rad).astype(np.int64), SWEEP_TABLE_BINS - 1)
    shared = np.flatnonzero(np.diff(bins) <= 0)
    if shared.size == 0:
        return None
    k = int(shared[0])
    return (f"{az.size} azimuths, rows {k} and {k + 1} are {np.degrees(float(az[k + 1]) - float(az[k])):.3g}° apart: "
            f"closer than the sweep form's bearing table resolves (one azimuth per {360.0 / SWEEP_TABLE_BINS:.3g}°, "
            f"at most {SWEEP_TABLE_BINS} rows), so its graph would draw this sweep wrong")


def sweep_form_fix(info, model_name: str) -> str:
    """What to do about a sweep the sweep form cannot draw: the model's own sweeps, and the stream form."""
    have = f"model {model_name} was made for sweeps of {info.sweep_geometry['num_azimuths']} azimuths; " if info else ""
    return (f"{have}use the stream form, which draws any azimuth count in the SDK (radar_odom.pretrained(NAME), "
            "`radar-odom export NAME`), or give the sweep form at most one row per 0.18° (e.g. the mean of every "
            "few rows)")


def check_sweep_feeds(feeds, info=None, model_name: str = "the sweep-form model") -> None:
    """Refuse sweep-form feeds (``power``, ``azimuths_rad``, ``range_resolution_m``, ``range_offset_m``: the
    sweep's arrays, docs/sweep-form.md) that the SDK path refuses as a sweep, with the SDK path's error types, so
    that a caller who builds the arrays by hand (or from a `RadarScan` made without `RadarScan.from_arrays`) gets
    the error instead of finite poses of garbage:

    - `ScanFormatError`, as `RadarScan.from_arrays` for the same fault: ``power`` not float32[A, B] with A, B ≥ 2
      (one row is no sweep), NaN or outside [0, 1] (8-bit data not divided by 255); ``azimuths_rad`` not float32[A],
      NaN, outside [0, 2π) (degrees), or not strictly increasing (a sweep listed backwards); a range resolution that
      is not a finite number > 0, or an offset that is not finite.
    - `ModelMismatchError`, as `check_sweep_geometry` for the same fault (``info``, the model's `ModelInfo`, given):
      range bins no radar has for the model, a sweep too short for its disc; and, for any sweep-form graph, azimuths
      closer than its bearing table can draw (`sweep_form_table_problem`: 4000 azimuths).

    Feeds missing a sweep input, or not a dict, are left to the runtime (whose error names the graph's inputs).
    Cheap: a min and a max over the power, the rest over A values.
    """
    if not isinstance(feeds, dict) or any(k not in feeds for k in SWEEP_INPUTS):
        return
    source = f"sweep feeds of {model_name}"
    where = f"{source}: "
    try:
        power, az, res, off = (np.asarray(feeds[k]) for k in SWEEP_INPUTS)
    except (ValueError, TypeError) as exc:
        raise ScanFormatError(f"{where}the sweep's arrays cannot be read as numeric arrays ({exc})") from None
    if power.ndim != 2 or power.shape[0] < 2 or power.shape[1] < 2:
        raise ScanFormatError(f"{where}power must be a 2-D array [azimuths, bins] of at least 2 rows and 2 bins "
                              f"(one row per azimuth of the turn), got shape {power.shape}")
    if power.dtype != np.float32:
        hint = "divide 8-bit data by 255" if power.dtype == np.uint8 else "convert it: power.astype(np.float32)"
        raise ScanFormatError(f"{where}power must be float32 in [0, 1], got dtype {power.dtype}; {hint}")
    rows = power.shape[0]
    if az.shape != (rows,):
        raise ScanFormatError(f"{where}azimuths_rad has shape {az.shape} but power has {rows} azimuth rows; "
                              "give one value per azimuth")
    if az.dtype != np.float32:
        raise ScanFormatError(f"{where}azimuths_rad must be float32 radians, got dtype {az.dtype}; convert it: "
                              "azimuths_rad.astype(np.float32)")
    for name, value in (("range_resolution_m", res), ("range_offset_m", off)):
        if value.shape != (1,) or value.dtype != np.float32:
            raise ScanFormatError(f"{where}{name} must be a float32[1] array (e.g. np.array([0.0432], "
                                  f"np.float32)), got dtype {value.dtype} shape {value.shape}")
        if not np.isfinite(value[0]):
            raise ScanFormatError(f"{where}{name} must be finite, got {float(value[0]):g}")
    if not res[0] > 0:
        raise ScanFormatError(f"{where}range_resolution_m must be > 0 metres per bin, got {float(res[0]):g}")
    if not np.all(np.isfinite(az)):
        raise ScanFormatError(f"{where}azimuths_rad holds NaN/inf")
    lo, hi = float(az.min()), float(az.max())
    if lo < 0 or hi >= 2 * np.pi + 1e-6:
        hint = ("; they look like degrees: give radians (np.radians)" if lo >= 0 and hi <= 360.0 else
                "; wrap them into [0, 2π) (np.mod(a, 2π)) and list the rows from the smallest" if lo < 0 else "")
        raise ScanFormatError(f"{where}azimuths_rad must lie in [0, 2π) radians, got [{lo:.4g}, {hi:.4g}]{hint}")
    steps = np.diff(az)
    if np.any(steps <= 0):
        bad = int(np.flatnonzero(steps <= 0)[0]) + 1
        hint = ("; they decrease: list the rows in increasing angle (power[::-1], azimuths_rad[::-1])"
                if np.all(steps < 0) else
                "; check encoder counts / azimuth order (a dropped row's angle must keep the list increasing: "
                "interpolate it by row index)")
        raise ScanFormatError(f"{where}azimuths must increase strictly within a sweep (row {bad}){hint}")
    plo, phi = float(power.min()), float(power.max())
    if not (plo >= 0.0 and phi <= 1.0):
        if not (np.isfinite(plo) and np.isfinite(phi)):
            raise ScanFormatError(f"{where}power holds NaN/inf values; clean or drop the sweep")
        raise ScanFormatError(f"{where}power must lie in [0, 1] (got [{plo:.3g}, {phi:.3g}]); divide 8-bit data "
                              "by 255")
    if info is not None:
        check_cartesian_bins(source, power.shape[1], float(res[0]), float(off[0]), info, model_name)
    why = sweep_form_table_problem(az)
    if why is not None:
        raise ModelMismatchError(f"{where}{why}; {sweep_form_fix(info, model_name)}")
