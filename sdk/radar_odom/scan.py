"""`RadarScan`: one polar radar sweep in memory, whatever file format it came from.

Frames and units: azimuth 0 points along the vehicle's +x (forward) axis and grows towards +y
(right), as encoder angles do on Navtech sensors; ranges are in metres,
``range_m[b] = range_offset_m + b * range_resolution_m`` for bin ``b`` (Oxford: offset 0;
Boreas: -0.31 m). Timestamps are UNIX microseconds, one per azimuth row.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import ScanFormatError

OXFORD_RANGE_RESOLUTION_M = 0.0432
OXFORD_ENCODER_SIZE = 5600
_INT64_LIMIT = float(2**63)
# a spinning radar's turn: longer row-time spans within one sweep are a corrupt header or wrong unit (issue 51: a 1 h
# jump inside one sweep was taken as a sweep)
MAX_SWEEP_SPAN_US = 5_000_000


def _finite_float(value, name: str, where: str) -> float:
    """``float(value)`` if it is a finite real number, else `ScanFormatError` naming ``name``."""
    if isinstance(value, (bool, np.bool_)):
        raise ScanFormatError(f"{where}{name} must be a number, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ScanFormatError(f"{where}{name} must be a number, got {value!r}") from None
    if not np.isfinite(out):
        raise ScanFormatError(f"{where}{name} must be finite, got {out!r}")
    return out


@dataclass(frozen=True)
class RadarScan:
    """One sweep.

    Attributes:
        timestamps_us: int64[A], UNIX µs of each azimuth row (≥ 0: not before 1970), non-decreasing.
        azimuths_rad: float32[A], in [0, 2π), strictly increasing.
        valid: bool[A], False for dropped azimuths (their ``power`` row is zeroed).
        power: float32[A, B] in [0, 1], B range bins.
        range_resolution_m: metres per range bin.
        range_offset_m: range of bin 0 (``range = offset + b * resolution``).
        encoder_counts: uint16[A] or None: raw encoder counts, kept for byte-exact writing.
        source: where it came from (a path or "arrays"), for error messages.
        invalid_rows: indices of rows that were invalid and zeroed (reported, never used).
    """

    timestamps_us: np.ndarray
    azimuths_rad: np.ndarray
    valid: np.ndarray
    power: np.ndarray
    range_resolution_m: float = OXFORD_RANGE_RESOLUTION_M
    range_offset_m: float = 0.0
    encoder_counts: np.ndarray | None = None
    source: str = "arrays"
    invalid_rows: tuple[int, ...] = field(default=())

    @property
    def num_azimuths(self) -> int:
        return int(self.power.shape[0])

    @property
    def num_bins(self) -> int:
        return int(self.power.shape[1])

    @property
    def timestamp_us(self) -> int:
        """Timestamp of the first azimuth (the Oxford file name)."""
        return int(self.timestamps_us[0])

    @property
    def max_range_m(self) -> float:
        return self.range_offset_m + self.num_bins * self.range_resolution_m

    @property
    def geometry(self) -> dict:
        """What a model depends on: azimuth count, bin count, range resolution and offset."""
        return {
            "num_azimuths": self.num_azimuths,
            "num_bins": self.num_bins,
            "range_resolution_m": float(self.range_resolution_m),
            "range_offset_m": float(self.range_offset_m),
        }

    @classmethod
    def from_arrays(
        cls,
        timestamps_us,
        azimuths_rad,
        power,
        valid=None,
        range_resolution_m: float = OXFORD_RANGE_RESOLUTION_M,
        range_offset_m: float = 0.0,
        encoder_counts=None,
        source: str = "arrays",
    ) -> RadarScan:
        """Build and validate a sweep from arrays (e.g. a live driver).

        ``power`` may be uint8 (0..255, scaled by 1/255) or float in [0, 1]. Raises
        `ScanFormatError` on mismatched lengths, non-numeric arrays, NaN/inf, non-increasing
        azimuths or timestamps, values outside [0, 1], timestamps beyond int64 µs, a range
        resolution that is not a finite number > 0 (or an offset that is not finite), encoder
        counts outside uint16, or when every row is invalid. Nothing is coerced silently:
        float timestamps are rounded to integer µs, nothing else changes value. Invalid rows
        are zeroed and listed in ``invalid_rows``.
        """
        where = f"{source}: "
        try:
            power = np.asarray(power)
            ts = np.asarray(timestamps_us)
            az = np.asarray(azimuths_rad)
        except (ValueError, TypeError) as exc:  # ragged nested lists and the like
            raise ScanFormatError(f"{where}arrays cannot be read as numeric arrays ({exc})") from None
        if power.ndim != 2 or power.shape[0] < 2 or power.shape[1] < 2:
            raise ScanFormatError(f"{where}power must be a 2-D array [azimuths, bins], got shape {power.shape}")
        a = power.shape[0]
        for name, arr in (("timestamps_us", ts), ("azimuths_rad", az)):
            if arr.shape != (a,):
                raise ScanFormatError(
                    f"{where}{name} has shape {arr.shape} but power has {a} azimuth rows; "
                    "give one value per azimuth"
                )
            if arr.dtype.kind not in "iuf":
                raise ScanFormatError(f"{where}{name} must be integer or float numbers, got dtype {arr.dtype}")
        res = _finite_float(range_resolution_m, "range_resolution_m", where)
        if res <= 0:
            raise ScanFormatError(
                f"{where}range_resolution_m must be > 0 metres per bin, got {res!r}"
            )
        offset = _finite_float(range_offset_m, "range_offset_m", where)
        if valid is None:
            valid = np.ones(a, dtype=bool)
        try:
            valid = np.asarray(valid)
        except (ValueError, TypeError) as exc:
            raise ScanFormatError(f"{where}valid cannot be read as an array ({exc})") from None
        if valid.shape != (a,):
            raise ScanFormatError(f"{where}valid has shape {valid.shape}, expected ({a},)")
        if valid.dtype.kind not in "biuf" or (valid.dtype.kind == "f" and not np.all(np.isfinite(valid))):
            raise ScanFormatError(f"{where}valid must be booleans (or 0/1 numbers), got dtype {valid.dtype}")
        valid = valid.astype(bool)
        if power.dtype == np.uint8:
            power = power.astype(np.float32) / np.float32(255.0)
        else:
            if not np.issubdtype(power.dtype, np.floating):
                raise ScanFormatError(f"{where}power must be uint8 or float, got {power.dtype}")
            power = power.astype(np.float32, copy=True)
            if not np.all(np.isfinite(power)):
                n = int(np.size(power) - np.count_nonzero(np.isfinite(power)))
                raise ScanFormatError(f"{where}power holds {n} NaN/inf values; clean or drop the sweep")
            lo, hi = float(power.min()), float(power.max())
            if lo < 0.0 or hi > 1.0:
                raise ScanFormatError(
                    f"{where}power must lie in [0, 1] (got [{lo:.3g}, {hi:.3g}]); divide 8-bit data by 255"
                )
        if ts.dtype.kind == "f":
            if not np.all(np.isfinite(ts)):
                raise ScanFormatError(f"{where}timestamps_us holds NaN/inf")
            ts = np.round(ts)
            # float64 cannot hold 2**63 - 1; anything at or beyond ±2**63 would wrap in int64
            if np.any(np.abs(ts) >= _INT64_LIMIT):
                raise ScanFormatError(
                    f"{where}timestamps_us holds {float(np.max(np.abs(ts))):.3g}, beyond the int64 range "
                    "of UNIX microseconds; give integer µs (a UNIX time now is about 1.7e15 µs)"
                )
        elif ts.dtype.kind == "u" and ts.size and int(ts.max()) > np.iinfo(np.int64).max:
            raise ScanFormatError(f"{where}timestamps_us holds {int(ts.max())}, beyond the int64 range")
        ts = ts.astype(np.int64)
        tv = ts[valid] if valid.shape == ts.shape else ts  # invalid rows carry garbage headers (Oxford: 0)
        if tv.size and int(tv.max()) - int(tv.min()) > MAX_SWEEP_SPAN_US:
            raise ScanFormatError(
                f"{where}timestamps_us span {(int(tv.max()) - int(tv.min())) / 1e6:.3g} s within one sweep; a spinning "
                f"radar turns in under {MAX_SWEEP_SPAN_US / 1e6:g} s (a Navtech in 0.25 s): the row times are corrupt "
                "or in the wrong unit (give µs)")
        if not np.all(np.isfinite(az)):
            raise ScanFormatError(f"{where}azimuths_rad holds NaN/inf")
        az = az.astype(np.float32)
        if not valid.any():
            raise ScanFormatError(f"{where}every azimuth row is marked invalid; the sweep holds no data")
        v_idx = np.flatnonzero(valid)
        if np.any(np.diff(az[v_idx]) <= 0):
            bad = int(v_idx[1:][np.diff(az[v_idx]) <= 0][0])
            raise ScanFormatError(
                f"{where}azimuths must increase strictly within a sweep (row {bad}); "
                "check encoder counts / azimuth order"
            )
        if az[v_idx].min() < 0 or az[v_idx].max() >= 2 * np.pi + 1e-6:
            raise ScanFormatError(f"{where}azimuths_rad must lie in [0, 2π)")
        if np.any(np.diff(ts[v_idx]) < 0):
            raise ScanFormatError(f"{where}azimuth timestamps go backwards within the sweep")
        if ts[v_idx].min() < 0:  # UNIX µs: no radar recording predates 1970; a sign or epoch error
            raise ScanFormatError(
                f"{where}timestamps_us holds {int(ts[v_idx].min())} µs, before 1970; give UNIX microseconds "
                "(a UNIX time now is about 1.7e15 µs), or times from 0 for a recording without a clock"
            )
        invalid = np.flatnonzero(~valid)
        if invalid.size:
            power[invalid] = 0.0
        enc = None
        if encoder_counts is not None:
            try:
                enc = np.asarray(encoder_counts)
            except (ValueError, TypeError) as exc:
                raise ScanFormatError(f"{where}encoder_counts cannot be read as an array ({exc})") from None
            if enc.shape != (a,) or enc.dtype.kind not in "iu":
                raise ScanFormatError(
                    f"{where}encoder_counts must be {a} integers (one per azimuth), got shape {enc.shape} "
                    f"dtype {enc.dtype}"
                )
            if enc.size and (int(enc.min()) < 0 or int(enc.max()) > 65535):
                raise ScanFormatError(f"{where}encoder_counts must lie in 0..65535 (uint16), got "
                                      f"[{int(enc.min())}, {int(enc.max())}]")
            enc = enc.astype(np.uint16)
        return cls(
            timestamps_us=ts,
            azimuths_rad=az,
            valid=valid,
            power=power,
            range_resolution_m=res,
            range_offset_m=offset,
            encoder_counts=enc,
            source=str(source),
            invalid_rows=tuple(int(i) for i in invalid),
        )
