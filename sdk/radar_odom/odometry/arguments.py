"""The odometer's argument checks: a configuration number or a stream timestamp that cannot be used
is refused with a typed error naming it (`ConfigError`, `StreamError`), never taken silently."""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError, StreamError


def config_number(value, name: str, low: float | None = None, high: float | None = None,
            open_low: bool = False) -> float:
    """``float(value)`` if finite and within the bounds, else `ConfigError` naming ``name``."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a number, got {value!r}") from None
    if isinstance(value, (bool, np.bool_)) or not math.isfinite(out):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    if low is not None and (out <= low if open_low else out < low):
        raise ConfigError(f"{name} must be {'>' if open_low else '≥'} {low:g}, got {out:g}")
    if high is not None and out > high:
        raise ConfigError(f"{name} must be ≤ {high:g}, got {out:g}")
    return out


def stream_timestamp(value, source: str) -> int:
    """An integer µs timestamp within int64, not before 1970 (negative), else `StreamError`."""
    try:
        out = int(value)
    except (TypeError, ValueError, OverflowError):
        raise StreamError(f"{source}: timestamp {value!r} is not an integer number of µs") from None
    if not -(2**63) <= out < 2**63:
        raise StreamError(f"{source}: timestamp {out} µs is beyond the int64 range")
    if out < 0:
        raise StreamError(f"{source}: timestamp {out} µs is before 1970; give UNIX microseconds (a UNIX time now is "
                          "about 1.7e15 µs), or times from 0 for a recording without a clock")
    return out
