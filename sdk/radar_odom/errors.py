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
    """An export cannot be made or its file fails a check: a request that cannot be met (form and
    search that do not go together, ...), an exporter that fails, a file that breaks a promise
    (opset, size, forbidden ops, checker), or onnxruntime's outputs differing from torch's beyond
    the tolerance. Defined here only; ``radar_odom_export`` raises this class."""


#: the PyTorch wheel index of CPU-only builds: without it pip fetches a multi-GB CUDA torch
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
TORCH_VERSION = "2.13.0"
#: the torch side's distribution (built from export/, its own pyproject.toml): training, export, calibration, adapt
EXPORT_DISTRIBUTION = "radar-odom-export"
#: how to install the torch side without a CUDA build, from a checkout or from an index
EXPORT_INSTALL_HINT = (
    f"pip install torch=={TORCH_VERSION} --extra-index-url {TORCH_CPU_INDEX} (the CPU build; a plain torch "
    f"requirement pulls a multi-GB CUDA build), then pip install {EXPORT_DISTRIBUTION} (in a checkout: "
    "pip install -e ./export)"
)


class MissingExtraError(RadarOdomError, ImportError):
    """An optional dependency is not installed; the message gives the pip lines (installed
    package and checkout). ``extra="export"`` names the torch side, a distribution of its own
    (``radar-odom-export``): the CPU torch build first, then that."""

    def __init__(self, module: str, extra: str | None, how: str | None = None, subject: str | None = None):
        if extra == "export":  # the torch side is a distribution of its own (radar-odom-export), not an extra
            how = EXPORT_INSTALL_HINT if how is None else how
            subject = subject or f"{module!r} is needed for this (the torch side, {EXPORT_DISTRIBUTION})"
        elif how is None:
            how = f"pip install \"radar-odom[{extra}]\" (in a checkout: pip install -e \".[{extra}]\")"
        which = f" (the {extra} extra)" if extra else ""
        subject = subject or f"{module!r} is needed for this{which}"
        super().__init__(f"{subject}; install it with: {how}")


class InvalidModelError(ModelMismatchError):
    """A model file is unusable: truncated or corrupt ONNX, metadata that is missing, malformed,
    of the wrong type or inconsistent with the graph's real inputs and outputs."""


class ModelNotFoundError(RadarOdomError, FileNotFoundError):
    """A model path that does not exist (a FileNotFoundError that is also a `RadarOdomError`)."""


class ModelDigestError(InvalidModelError):
    """A registered model file (`radar_odom.pretrained`, the model registry) whose SHA-256 is not the one its
    registry records: damaged or replaced since it was installed or added. The message names the file, the
    expected and the found digest and what to do (reinstall radar-odom, or add the local model again)."""

    def __init__(self, message: str, path=None, expected: str | None = None, found: str | None = None):
        super().__init__(message)
        self.path = path
        self.expected = expected
        self.found = found


class RegistryError(RadarOdomError, ValueError):
    """A model registry file (``registry.json``: the shipped one or ``$RADAR_ODOM_HOME/models/registry.json``)
    that cannot be read or holds a malformed entry; the message names the file and the entry."""


class ConfigError(RadarOdomError, ValueError):
    """An argument value the SDK cannot work with (NaN, out of range, unknown choice)."""


class InputTypeError(RadarOdomError, TypeError):
    """An argument of the wrong kind (a numpy array where a `RadarScan` belongs, ...); the message says what to
    pass instead (a TypeError that is also a `RadarOdomError`)."""


class GridError(ConfigError, MemoryError):
    """A Cartesian grid the SDK will not allocate (thousands of pixels a side: gigabytes of sample maps); a
    `ConfigError` that is also the MemoryError numpy would have raised, with the size and what to give instead."""


class OutputError(RadarOdomError, OSError):
    """An output path cannot be written (e.g. ``-o`` names an existing file)."""


class ClusterError(RadarOdomError, ConnectionError):
    """A Ray cluster that cannot be reached or started (``--address``): the message names the address and the
    reason (nothing listening there, no answer within the connect timeout, no cluster to join)."""


class RunAborted(RadarOdomError):
    """``run_sequence(..., on_error="stop")`` met a sweep it could not use.

    ``result`` holds what was computed (and written) before that sweep; ``cause`` the error.
    """

    def __init__(self, message: str, result=None, cause: Exception | None = None):
        super().__init__(message)
        self.result = result
        self.cause = cause


class RunInterrupted(KeyboardInterrupt):
    """``run_sequence`` was interrupted (Ctrl-C's `KeyboardInterrupt`, or what a caller raises for SIGTERM) during
    the odometry: the outputs so far are written, marked partial, as ``on_error="stop"`` writes them.

    A `KeyboardInterrupt` still (a caller's ``except KeyboardInterrupt`` keeps working), not a `RadarOdomError`.
    The message says at which sweep and where the outputs are; ``result`` holds them (None where none could be
    written); ``cause`` is the interrupt that stopped the run.
    """

    def __init__(self, message: str, result=None, cause: BaseException | None = None):
        super().__init__(message)
        self.result = result
        self.cause = cause


class GroundTruthWarning(UserWarning):
    """Ground-truth rows that were left out (non-finite values, conflicting duplicates); the
    message names the file and line numbers. The pairs they would have covered have no ground
    truth (NaN), the rest is used as it is."""


class StampWarning(UserWarning):
    """Sweep stamps that a recording host stamped late and that were put back on the sensor's period
    (`radar_odom.io.stamps`); the message says how many, by how much, and how to keep them as recorded."""


class FormatWarning(UserWarning):
    """An explicit ``format=`` that the file contradicts (its folder or its header): the sweep is read
    as asked, with that dataset's range resolution, which may be wrong for it."""
