"""An exported radar-odom ONNX file at run time: the onnxruntime session and what its metadata says.

The exporter (``radar_odom_export.onnx_export``) writes every fact the runtime needs into the
file's ``metadata_props`` under ``radar_odom.*`` keys (`METADATA_KEYS`); `ModelInfo` reads them
back, so nothing about a model is ever re-typed at run time:

- ``radar_odom.profile``: the `GridProfile` JSON (`GridProfile.to_metadata`).
- ``radar_odom.form``: ``"stream"`` (inputs: current sweep + previous state; outputs: pose,
  covariance, state) or ``"pair"`` (inputs: previous and current sweep; outputs: pose, covariance).
- ``radar_odom.sweep_geometry``: JSON ``{num_azimuths, num_bins, range_resolution_m,
  range_offset_m}`` of the sweeps the model was trained on.
- ``radar_odom.inputs`` / ``radar_odom.outputs``: JSON lists of tensor names, in graph order.
- ``radar_odom.input_shape``: JSON shape of one sweep input (``[1, W, W]`` Cartesian or
  ``[1, A, B']`` polar); ``radar_odom.state_shape``: JSON shape of the stream state.
- ``radar_odom.polar_input``: JSON ``{num_bins, bin_factor}`` for polar models (how the polar
  sweep is reduced before the graph); absent for Cartesian models.
- ``radar_odom.masking``, ``radar_odom.training_data``, ``radar_odom.version``,
  ``radar_odom.opset``, ``radar_odom.exporter``: provenance.
- ``radar_odom.search``: JSON settings of the coarse-to-fine yaw search (`fast_search`); absent
  when every yaw candidate is scored.

Threads: onnxruntime runs one worker per *physical* core by default (`physical_cores`); SMT
siblings share the FPUs the matmuls saturate, so counting them makes each step slower.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ModelMismatchError
from .profiles import GridProfile

FORMAT = "radar-odom-onnx/1"
METADATA_KEYS = (
    "radar_odom.format",
    "radar_odom.profile",
    "radar_odom.form",
    "radar_odom.sweep_geometry",
    "radar_odom.inputs",
    "radar_odom.outputs",
    "radar_odom.input_shape",
    "radar_odom.state_shape",
    "radar_odom.masking",
    "radar_odom.training_data",
    "radar_odom.version",
    "radar_odom.opset",
    "radar_odom.exporter",
    "radar_odom.search",
)
GEOMETRY_KEYS = ("num_azimuths", "num_bins", "range_resolution_m", "range_offset_m")


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


def session_options(threads: int | None = None, enable_profiling: bool = False, profile_prefix=None):
    """onnxruntime ``SessionOptions`` for a one-sweep-at-a-time stream.

    ``threads`` intra-op workers (default: `physical_cores`), one inter-op worker and sequential
    execution (the graph is a single chain, parallel branches would only contend for cores),
    all graph optimisations on. ``enable_profiling`` writes onnxruntime's per-node JSON trace.
    """
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads) if threads else physical_cores()
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3  # warnings about unused initializers etc. are noise for users
    if enable_profiling:
        so.enable_profiling = True
        if profile_prefix:
            so.profile_file_prefix = str(profile_prefix)
    return so


@dataclass(frozen=True)
class ModelInfo:
    """Everything the metadata of a radar-odom ONNX file says (see the module docstring)."""

    profile: GridProfile
    form: str
    sweep_geometry: dict
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    input_shape: tuple[int, ...]
    state_shape: tuple[int, ...] | None
    polar_input: dict | None
    masking: str
    training_data: str
    version: str
    opset: int | None
    exporter: str
    source: str
    search: dict | None = None  # fast-search settings; None: every yaw candidate is scored

    @classmethod
    def from_metadata(cls, meta: dict[str, str], source: str = "model") -> "ModelInfo":
        """Parse ``radar_odom.*`` metadata; raise `ModelMismatchError` if it is not a radar-odom model."""
        if meta.get("radar_odom.format") != FORMAT or "radar_odom.profile" not in meta:
            raise ModelMismatchError(
                f"{source}: not a radar-odom model (metadata 'radar_odom.format' is "
                f"{meta.get('radar_odom.format')!r}, expected {FORMAT!r}); export one with "
                "`radar-odom export model.pt`"
            )

        def js(key, default=None):
            return json.loads(meta[key]) if key in meta else default

        form = meta.get("radar_odom.form", "")
        if form not in ("stream", "pair"):
            raise ModelMismatchError(f"{source}: metadata form {form!r} is neither 'stream' nor 'pair'")
        geometry = js("radar_odom.sweep_geometry", {})
        missing = [k for k in GEOMETRY_KEYS if k not in geometry]
        if missing:
            raise ModelMismatchError(f"{source}: metadata sweep_geometry lacks {missing}")
        state = js("radar_odom.state_shape")
        opset = meta.get("radar_odom.opset")
        return cls(
            profile=GridProfile.from_metadata(meta),
            form=form,
            sweep_geometry=geometry,
            inputs=tuple(js("radar_odom.inputs", [])),
            outputs=tuple(js("radar_odom.outputs", [])),
            input_shape=tuple(js("radar_odom.input_shape", [])),
            state_shape=None if state is None else tuple(state),
            polar_input=js("radar_odom.polar_input"),
            masking=meta.get("radar_odom.masking", "unknown"),
            training_data=meta.get("radar_odom.training_data", ""),
            version=meta.get("radar_odom.version", ""),
            opset=int(opset) if opset else None,
            exporter=meta.get("radar_odom.exporter", ""),
            source=source,
            search=js("radar_odom.search"),
        )

    @property
    def sweep_input(self) -> str:
        """Name of the current-sweep input (``cart`` or ``polar``)."""
        return "polar" if self.profile.input_kind == "polar" else "cart"


class OnnxModel:
    """An onnxruntime session over a radar-odom ONNX file, with its `ModelInfo`.

    ``run(feeds)`` takes float32 arrays by input name and returns a dict of outputs by name.
    """

    def __init__(self, path, threads: int | None = None, providers=None, enable_profiling=False,
                 profile_prefix=None):
        import onnxruntime as ort

        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(
                f"{self.path}: no such model file; give a path to an exported .onnx or a name from "
                "radar_odom.pretrained_names()"
            )
        self.session = ort.InferenceSession(
            str(self.path),
            sess_options=session_options(threads, enable_profiling, profile_prefix),
            providers=list(providers) if providers else ["CPUExecutionProvider"],
        )
        meta = dict(self.session.get_modelmeta().custom_metadata_map)
        self.info = ModelInfo.from_metadata(meta, source=str(self.path))
        self._check_signature()

    def _check_signature(self):
        """The graph's real inputs/outputs must be the ones the metadata promises."""
        ins = tuple(i.name for i in self.session.get_inputs())
        outs = tuple(o.name for o in self.session.get_outputs())
        if self.info.inputs and ins != self.info.inputs:
            raise ModelMismatchError(f"{self.path}: graph inputs {ins} differ from metadata {self.info.inputs}")
        if not {"pose", "covariance"} <= set(outs):
            raise ModelMismatchError(f"{self.path}: graph outputs {outs} lack 'pose'/'covariance'")
        self.output_names = [o for o in outs]

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        values = self.session.run(self.output_names, feeds)
        return dict(zip(self.output_names, values))

    def end_profiling(self) -> str:
        """Stop onnxruntime's profiler and return the JSON trace path."""
        return self.session.end_profiling()
