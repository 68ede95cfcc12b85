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


@dataclass(frozen=True)
class RadarScan:
    """One sweep.

    Attributes:
        timestamps_us: int64[A], UNIX µs of each azimuth row, non-decreasing.
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
    ) -> "RadarScan":
        """Build and validate a sweep from arrays (e.g. a live driver).

        ``power`` may be uint8 (0..255, scaled by 1/255) or float in [0, 1]. Raises
        `ScanFormatError` on mismatched lengths, NaN/inf, non-increasing azimuths or
        timestamps, values outside [0, 1], or when every row is invalid. Invalid rows are
        zeroed and listed in ``invalid_rows``.
        """
        where = f"{source}: "
        power = np.asarray(power)
        if power.ndim != 2 or power.shape[0] < 2 or power.shape[1] < 2:
            raise ScanFormatError(f"{where}power must be a 2-D array [azimuths, bins], got shape {power.shape}")
        a = power.shape[0]
        ts = np.asarray(timestamps_us)
        az = np.asarray(azimuths_rad)
        for name, arr in (("timestamps_us", ts), ("azimuths_rad", az)):
            if arr.shape != (a,):
                raise ScanFormatError(
                    f"{where}{name} has shape {arr.shape} but power has {a} azimuth rows; "
                    "give one value per azimuth"
                )
        if valid is None:
            valid = np.ones(a, dtype=bool)
        valid = np.asarray(valid)
        if valid.shape != (a,):
            raise ScanFormatError(f"{where}valid has shape {valid.shape}, expected ({a},)")
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
        if not np.issubdtype(ts.dtype, np.integer):
            if not np.all(np.isfinite(ts)):
                raise ScanFormatError(f"{where}timestamps_us holds NaN/inf")
            ts = np.round(ts)
        ts = ts.astype(np.int64)
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
        invalid = np.flatnonzero(~valid)
        if invalid.size:
            power[invalid] = 0.0
        enc = None if encoder_counts is None else np.asarray(encoder_counts).astype(np.uint16)
        return cls(
            timestamps_us=ts,
            azimuths_rad=az,
            valid=valid,
            power=power,
            range_resolution_m=float(range_resolution_m),
            range_offset_m=float(range_offset_m),
            encoder_counts=enc,
            source=source,
            invalid_rows=tuple(int(i) for i in invalid),
        )
