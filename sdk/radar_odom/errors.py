"""Typed errors of the SDK. Each message names the file or input and says what to do."""


class RadarOdomError(Exception):
    """Base class of every error the SDK raises on purpose."""


class ScanFormatError(RadarOdomError, ValueError):
    """A radar sweep (file or arrays) is malformed: wrong shape, depth, truncated, NaN, ..."""


class SequenceError(RadarOdomError, ValueError):
    """A recording folder is incomplete or inconsistent (missing radar/, bad ground truth, ...)."""


class ModelMismatchError(RadarOdomError, ValueError):
    """A scan does not fit the ONNX model's metadata (sweep geometry, resolution, ...)."""


class StreamError(RadarOdomError, ValueError):
    """A stream of sweeps is broken: timestamps go backwards or jump by more than allowed."""


class ExportError(RadarOdomError, ValueError):
    """An export request cannot be met (form and search that do not go together, ...)."""


class MissingExtraError(RadarOdomError, ImportError):
    """An optional dependency is not installed; the message gives the pip line."""

    def __init__(self, module: str, extra: str):
        super().__init__(
            f"{module!r} is needed for this; install it with: pip install \"radar-odom[{extra}]\""
        )
