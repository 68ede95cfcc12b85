"""An exported radar-odom ONNX file at run time: the onnxruntime session and what its metadata says.

The file's contract (its ``radar_odom.*`` metadata keys, their types, and how they must agree
with the profile and with the graph) lives in `radar_odom.model_file`, shared with the exporter;
`OnnxModel` loads the file, reads its metadata with `ModelInfo.from_metadata` and holds the graph
onnxruntime actually loaded to it (`model_file.check_signature`: input/output names, shapes,
float tensors). A truncated or corrupt file, or a graph onnxruntime cannot load or run, is an
`InvalidModelError` too, never a raw onnxruntime exception.

Threads: onnxruntime runs one worker per *physical* core by default (`physical_cores`); SMT
siblings share the FPUs the matmuls saturate, so counting them makes each step slower.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import ConfigError, InvalidModelError, ModelNotFoundError
from .model_file import FORMAT, GEOMETRY_KEYS, ModelInfo, check_signature, profile_digest
from .sweep_arrays import check_sweep_feeds

__all__ = ["FORMAT", "GEOMETRY_KEYS", "ModelInfo", "OnnxModel", "physical_cores", "profile_digest",
           "session_options"]


def count_physical_cores(cpuinfo_text: str, allowed: set[int] | None = None) -> int:
    """Distinct ``(physical id, core id)`` pairs in ``/proc/cpuinfo`` text (0 if it has none).

    Only processors in ``allowed`` (e.g. ``os.sched_getaffinity(0)``) count, when given.
    """
    cores = set()
    for block in cpuinfo_text.strip().split("\n\n"):
        fields = {k.strip(): v.strip() for k, _, v in (ln.partition(":") for ln in block.splitlines())}
        if "processor" not in fields or "core id" not in fields:
            continue
        if allowed is not None and int(fields["processor"]) not in allowed:
            continue
        cores.add((fields.get("physical id", "0"), fields["core id"]))
    return len(cores)


def physical_cores() -> int:
    """Physical cores this process may run on (SMT siblings counted once).

    Counts distinct ``(physical id, core id)`` pairs in ``/proc/cpuinfo`` among the CPUs of
    ``os.sched_getaffinity`` (Linux); falls back to the affinity set's size, then to
    ``os.cpu_count()``, where that file is missing or has no core ids (some ARM kernels).
    """
    try:
        allowed = os.sched_getaffinity(0)
    except (AttributeError, OSError):
        allowed = None
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        text = ""
    n = count_physical_cores(text, allowed)
    if n:
        return n
    if allowed:
        return len(allowed)
    return os.cpu_count() or 1


# more workers than this per logical CPU only contend; onnxruntime starts every one it is asked for
# (100000 hung a run), so a larger count is a mistake to report, not a request to honour
MAX_THREADS_PER_CPU = 4


def check_threads(threads, name: str = "threads") -> int | None:
    """``threads`` as an int, None kept (the default: `physical_cores`), or `ConfigError` naming ``name``.

    A whole number ≥ 1 and at most `MAX_THREADS_PER_CPU` × the logical CPUs here; a string, a float
    (1.5 was truncated to 1), a bool or a negative count is refused, not coerced.
    """
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)):
        raise ConfigError(f"{name} must be a whole number of threads ≥ 1 (or None: one per physical core), got "
                          f"{type(threads).__name__} {threads!r}")
    cpus = os.cpu_count() or 1
    cap = MAX_THREADS_PER_CPU * cpus
    if threads < 1:
        raise ConfigError(f"{name} must be ≥ 1 (or None: one per physical core), got {int(threads)}")
    if threads > cap:
        raise ConfigError(f"{name}={int(threads)} is more than {cap} ({MAX_THREADS_PER_CPU} per CPU, {cpus} CPUs "
                          f"here); every one would be started and they would only contend — give at most {cap}, or "
                          f"leave it out for one per physical core ({physical_cores()})")
    return int(threads)


OPTIMIZATION_LEVELS = ("basic", "extended", "all")


def session_options(threads: int | None = None, enable_profiling: bool = False, profile_prefix=None,
                    spinning: bool = False, optimization: str | None = None):
    """onnxruntime ``SessionOptions`` for a one-sweep-at-a-time stream.

    ``threads`` intra-op workers (default: `physical_cores`; `check_threads`), one inter-op worker and sequential
    execution (the graph is a single chain, parallel branches would only contend for cores).
    ``optimization``: onnxruntime's graph optimisation level, ``"all"`` by default (its own default:
    NCHWc convolution layouts and every fusion); ``"basic"`` measured from 0.7× to 1.13× its step
    time on a shared 2-core machine, so the default stays (docs/latency.md, "Half the step").
    ``enable_profiling`` writes onnxruntime's per-node JSON trace.
    ``spinning``: let the intra-op workers busy-wait between operators (onnxruntime's default). Off
    here: most of the step's ~850 operators are small, so a spinning worker holds a core it does not
    use, the core the read-ahead thread needs to decode the next sweep, or another process's
    (docs/latency.md, "Pipeline").
    """
    import onnxruntime as ort

    threads = check_threads(threads)
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads or physical_cores()
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    if optimization not in (None, *OPTIMIZATION_LEVELS):
        raise ConfigError(f"optimization must be one of {OPTIMIZATION_LEVELS}, got {optimization!r}")
    so.graph_optimization_level = {
        "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
        "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
        "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
    }[optimization or "all"]
    so.log_severity_level = 3  # warnings about unused initializers etc. are noise for users
    so.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    if enable_profiling:
        so.enable_profiling = True
        if profile_prefix:
            so.profile_file_prefix = str(profile_prefix)
    return so



def is_torch_checkpoint(path) -> bool:
    """True for a file that is a PyTorch checkpoint: a ``.pt`` / ``.pth`` name, or a zip archive (``torch.save``'s
    format; an ONNX file is a protobuf and never starts with the zip signature). Read without torch."""
    path = Path(path)
    if path.suffix.lower() in (".pt", ".pth"):
        return True
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PK\x03\x04"
    except OSError:
        return False

class OnnxModel:
    """An onnxruntime session over a radar-odom ONNX file, with its `ModelInfo`.

    ``run(feeds)`` takes float32 arrays by input name and returns a dict of outputs by name.
    ``spinning``, ``optimization``: `session_options`' (off; "all" by default).
    ``providers``: onnxruntime's (default: its CPU provider alone). ``ep_devices``, ``ep_options``: a plugin
    execution provider's devices (``onnxruntime.get_ep_devices()``) and options, in place of ``providers``.
    ``session_config``: onnxruntime session configuration entries (``SessionOptions.add_session_config_entry``).
    """

    def __init__(self, path, threads: int | None = None, providers=None, enable_profiling=False,
                 profile_prefix=None, spinning: bool = False, optimization: str | None = None,
                 ep_devices=None, ep_options: dict | None = None, session_config: dict | None = None):
        import onnxruntime as ort

        check_threads(threads)  # before the session: a bad count is not a corrupt file
        self.path = Path(path)
        if not self.path.is_file():
            raise ModelNotFoundError(
                f"{self.path}: no such model file; give a path to an exported .onnx or a name from "
                "radar_odom.pretrained_names()"
            )
        if is_torch_checkpoint(self.path):  # onnxruntime would only say INVALID_PROTOBUF
            raise InvalidModelError(
                f"{self.path}: is a PyTorch checkpoint (what `radar-odom train` / `adapt` write), not an ONNX model; "
                f"export it first: radar-odom export {self.path} (writes {self.path.with_suffix('.onnx')}), then "
                "give that .onnx file"
            )
        so = session_options(threads, enable_profiling, profile_prefix, spinning, optimization)
        if ep_devices:
            so.add_provider_for_devices(list(ep_devices), dict(ep_options or {}))
        for key, value in (session_config or {}).items():
            so.add_session_config_entry(key, value)
        try:
            self.session = ort.InferenceSession(
                str(self.path), sess_options=so,
                providers=None if ep_devices else list(providers) if providers else ["CPUExecutionProvider"],
            )
            meta = dict(self.session.get_modelmeta().custom_metadata_map)
        except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own pybind11 exception types
            detail = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise InvalidModelError(
                f"{self.path}: onnxruntime cannot load this model ({detail}); the file is truncated, "
                "corrupt or not ONNX — re-copy or re-export it"
            ) from None
        self.info = ModelInfo.from_metadata(meta, source=str(self.path))
        self._check_signature()

    def _check_signature(self):
        """The graph's real inputs/outputs must be the ones the metadata promises (names, shapes)."""
        def described(args):
            return [(a.name, a.shape, a.type) for a in args]

        outputs = self.session.get_outputs()
        check_signature(self.info, described(self.session.get_inputs()), described(outputs), source=str(self.path))
        self.output_names = [o.name for o in outputs]

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Outputs by name for float32 ``feeds`` by input name. A sweep-form model's sweep arrays are checked first
        as the SDK path checks a sweep (`radar_odom.sweep_arrays.check_sweep_feeds`: `ScanFormatError`,
        `ModelMismatchError`); a feed the graph cannot run is an `InvalidModelError`."""
        if self.info.form == "sweep":
            check_sweep_feeds(feeds, self.info, self.path.name)
        try:
            values = self.session.run(self.output_names, feeds)
        except Exception as exc:  # noqa: BLE001 - onnxruntime's own exception types
            detail = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise InvalidModelError(
                f"{self.path}: onnxruntime failed running the model ({detail}); the graph does not "
                "match its metadata — re-export it"
            ) from None
        return dict(zip(self.output_names, values))

    def end_profiling(self) -> str:
        """Stop onnxruntime's profiler and return the JSON trace path."""
        return self.session.end_profiling()
