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
- ``radar_odom.profile_sha256``: SHA-256 (hex) of the ``radar_odom.profile`` text, written by
  exporters from this version on; when present, a profile edited by hand is refused.

Validation (`ModelInfo.from_metadata`, `OnnxModel`): the metadata is one schema shared by the
exporter (which validates what it writes with `ModelInfo.from_metadata`) and the runtime. A
missing required key, text that is not JSON, a value of the wrong type or out of range, a
profile inconsistent with the sweep input's shape (e.g. ``width_px`` against ``[1, W, W]``) or
with its digest → `InvalidModelError` (a `ModelMismatchError`) naming the key. `OnnxModel` then
checks the metadata against the graph onnxruntime actually loaded (input/output names, shapes,
float tensors); a truncated or corrupt file, or a graph onnxruntime cannot load or run, is an
`InvalidModelError` too, never a raw onnxruntime exception. A scale change that keeps every
shape (``resolution_m`` edited together with its digest) cannot be detected from the file.

Threads: onnxruntime runs one worker per *physical* core by default (`physical_cores`); SMT
siblings share the FPUs the matmuls saturate, so counting them makes each step slower.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

import numpy as np

from .errors import InvalidModelError, ModelMismatchError, ModelNotFoundError
from .profiles import GridProfile

FORMAT = "radar-odom-onnx/1"
REQUIRED_KEYS = (
    "radar_odom.format",
    "radar_odom.profile",
    "radar_odom.form",
    "radar_odom.sweep_geometry",
    "radar_odom.inputs",
    "radar_odom.outputs",
    "radar_odom.input_shape",
)
METADATA_KEYS = REQUIRED_KEYS + (
    "radar_odom.state_shape",
    "radar_odom.masking",
    "radar_odom.training_data",
    "radar_odom.version",
    "radar_odom.opset",
    "radar_odom.exporter",
    "radar_odom.search",
    "radar_odom.profile_sha256",
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


def profile_digest(profile_text: str) -> str:
    """SHA-256 hex of the ``radar_odom.profile`` metadata text (``radar_odom.profile_sha256``)."""
    return hashlib.sha256(profile_text.encode("utf-8")).hexdigest()


_TYPE_NAMES = {dict: "object", list: "array", str: "string"}
# GridProfile fields whose range its own checks leave open (a negative window, a zero step...)
_PROFILE_RANGES = {
    "max_translation_m": (0.0, False), "rotation_range_rad": (0.0, False),
    "rotation_step_rad": (0.0, True), "beta_pose": (0.0, True), "beta_cov": (0.0, True),
    "near_range_m": (0.0, False), "unet_base_channels": (1, False), "unet_depth": (0, False),
    "cov_floor_cells": (0.0, False), "pose_window_cells": (0, False),
}
MAX_ROTATIONS = 7201  # candidates; a 0.05° step over ±180°


class _Validator:
    """Typed reads of one metadata dict, each failure an `InvalidModelError` naming the key."""

    def __init__(self, meta: dict, source: str):
        self.meta, self.source = meta, source

    def fail(self, key: str, what: str):
        raise InvalidModelError(f"{self.source}: metadata {key!r} {what}; re-export the model with `radar-odom export`")

    def json(self, key: str, kind, required: bool = True):
        if key not in self.meta:
            if required:
                self.fail(key, "is missing")
            return None
        try:
            value = json.loads(self.meta[key])
        except (ValueError, RecursionError) as exc:
            self.fail(key, f"is not valid JSON ({str(exc)[:80]})")
        if value is None and not required:
            return None
        if not isinstance(value, kind):
            self.fail(key, f"must be a JSON {_TYPE_NAMES.get(kind, kind.__name__)}, got {type(value).__name__}")
        return value

    def check_int(self, d: dict, k: str, key: str, low: int | None = None) -> int:
        x = d.get(k, MISSING)
        if x is MISSING:
            self.fail(key, f"lacks {k!r}")
        if isinstance(x, bool) or not isinstance(x, int):
            self.fail(key, f"field {k!r} must be an integer, got {x!r}")
        if low is not None and x < low:
            self.fail(key, f"field {k!r} must be ≥ {low}, got {x}")
        return x

    def check_float(self, d: dict, k: str, key: str, low: float | None = None, open_low: bool = False) -> float:
        x = d.get(k, MISSING)
        if x is MISSING:
            self.fail(key, f"lacks {k!r}")
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            self.fail(key, f"field {k!r} must be a finite number, got {x!r}")
        if low is not None and (x <= low if open_low else x < low):
            self.fail(key, f"field {k!r} must be {'>' if open_low else '≥'} {low:g}, got {x!r}")
        return float(x)

    def names(self, key: str, count: int | None) -> tuple[str, ...]:
        value = self.json(key, list)
        if not value or not all(isinstance(n, str) and n for n in value) or len(set(value)) != len(value):
            self.fail(key, f"must be a list of distinct tensor names, got {value!r:.80}")
        if count is not None and len(value) != count:
            self.fail(key, f"must name {count} tensors, got {len(value)}")
        return tuple(value)

    def shape(self, key: str, required: bool = True) -> tuple[int, ...] | None:
        value = self.json(key, list, required=required)
        if value is None:
            return None
        if not value or len(value) > 8 or not all(isinstance(n, int) and not isinstance(n, bool) and 0 < n < 2**31
                                                  for n in value):
            self.fail(key, f"must be a list of positive integer dimensions, got {value!r:.80}")
        return tuple(value)

    def profile(self) -> GridProfile:
        key = "radar_odom.profile"
        text = self.meta[key]
        digest = self.meta.get("radar_odom.profile_sha256")
        if digest is not None and digest.strip().lower() != profile_digest(text):
            self.fail(key, "does not match its digest 'radar_odom.profile_sha256' (the profile was edited)")
        d = self.json(key, dict)
        kw = {}
        for f in fields(GridProfile):
            if f.name not in d:
                if f.default is MISSING:
                    self.fail(key, f"lacks {f.name!r}")
                continue
            x = d[f.name]
            kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
            if kind == "float":
                self.check_float(d, f.name, key)
                x = float(x)
            elif kind == "int":
                self.check_int(d, f.name, key)
            elif kind == "str" and not isinstance(x, str):
                self.fail(key, f"field {f.name!r} must be a string, got {x!r}")
            if f.name in _PROFILE_RANGES:
                low, open_low = _PROFILE_RANGES[f.name]
                if x < low or (open_low and x == low):
                    self.fail(key, f"field {f.name!r} must be {'>' if open_low else '≥'} {low}, got {x!r}")
            kw[f.name] = x
        for name, cap in (("width_px", 2**16), ("unet_depth", 16), ("mask_downsample", 2**10),
                          ("unet_base_channels", 2**12), ("pose_window_cells", 2**16)):
            if name in kw and kw[name] > cap:
                self.fail(key, f"field {name!r} is implausibly large ({kw[name]}; at most {cap})")
        if "rotation_range_rad" in kw and kw["rotation_range_rad"] > math.pi:
            self.fail(key, f"field 'rotation_range_rad' must be ≤ π, got {kw['rotation_range_rad']!r}")
        step = kw.get("rotation_step_rad", GridProfile.rotation_step_rad)
        rng = kw.get("rotation_range_rad", GridProfile.rotation_range_rad)
        if 2 * rng / step + 1 > MAX_ROTATIONS:
            self.fail(key, f"asks for {2 * rng / step + 1:.3g} yaw candidates (at most {MAX_ROTATIONS})")
        try:
            return GridProfile(**kw)
        except (ValueError, TypeError, ZeroDivisionError, OverflowError) as exc:
            self.fail(key, f"is inconsistent ({exc})")


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
        """Parse and validate ``radar_odom.*`` metadata.

        Raises `ModelMismatchError` if it is not a radar-odom model at all, `InvalidModelError`
        (naming the key) if a required key is missing, not JSON, of the wrong type, out of range
        or inconsistent with another (see the module docstring).
        """
        if not isinstance(meta, dict):
            raise InvalidModelError(f"{source}: metadata must be a dict of strings, got {type(meta).__name__}")
        if meta.get("radar_odom.format") != FORMAT or "radar_odom.profile" not in meta:
            raise ModelMismatchError(
                f"{source}: not a radar-odom model (metadata 'radar_odom.format' is "
                f"{meta.get('radar_odom.format')!r}, expected {FORMAT!r}); export one with "
                "`radar-odom export model.pt`"
            )
        bad = [k for k, v in meta.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise InvalidModelError(f"{source}: metadata {bad[0]!r} is not text")
        missing = [k for k in REQUIRED_KEYS if k not in meta]
        if missing:
            raise InvalidModelError(
                f"{source}: metadata lacks {', '.join(repr(k) for k in missing)}; the file was edited "
                "or written by a foreign tool — re-export it with `radar-odom export`"
            )
        v = _Validator(meta, source)
        form = meta["radar_odom.form"]
        if form not in ("stream", "pair"):
            raise InvalidModelError(f"{source}: metadata 'radar_odom.form' is {form!r}, neither 'stream' nor 'pair'")
        profile = v.profile()
        geometry = v.json("radar_odom.sweep_geometry", dict)
        for k in ("num_azimuths", "num_bins"):
            v.check_int(geometry, k, "radar_odom.sweep_geometry", low=2)
        v.check_float(geometry, "range_resolution_m", "radar_odom.sweep_geometry", low=0.0, open_low=True)
        v.check_float(geometry, "range_offset_m", "radar_odom.sweep_geometry")
        inputs = v.names("radar_odom.inputs", 2)
        outputs = v.names("radar_odom.outputs", None)
        for need in ("pose", "covariance") + (("state",) if form == "stream" else ()):
            if need not in outputs:
                raise InvalidModelError(f"{source}: metadata 'radar_odom.outputs' {outputs} lacks {need!r}")
        input_shape = v.shape("radar_odom.input_shape")
        state = v.shape("radar_odom.state_shape", required=form == "stream")
        polar = v.json("radar_odom.polar_input", dict, required=profile.input_kind == "polar")
        if polar is not None:
            v.check_int(polar, "num_bins", "radar_odom.polar_input", low=1)
            v.check_int(polar, "bin_factor", "radar_odom.polar_input", low=1)
            if polar["num_bins"] * polar["bin_factor"] > geometry["num_bins"]:
                raise InvalidModelError(
                    f"{source}: metadata 'radar_odom.polar_input' reads {polar['num_bins']} × "
                    f"{polar['bin_factor']} bins, more than the sweep geometry's {geometry['num_bins']}"
                )
        # the sweep input's shape follows from the profile: a hand-edited grid is caught here
        if profile.input_kind == "polar":
            want = (1, geometry["num_azimuths"], polar["num_bins"])
        else:
            want = (1, profile.width_px, profile.width_px)
        if input_shape != want:
            raise InvalidModelError(
                f"{source}: metadata 'radar_odom.input_shape' {list(input_shape)} does not match the "
                f"profile ({list(want)} for {profile.input_kind} input, width_px {profile.width_px}); "
                "the metadata was edited — re-export the model"
            )
        opset = meta.get("radar_odom.opset")
        if opset is not None and not (opset.strip().isascii() and opset.strip().isdigit() and len(opset.strip()) < 7):
            raise InvalidModelError(f"{source}: metadata 'radar_odom.opset' is {opset[:40]!r}, not an integer")
        search = v.json("radar_odom.search", dict, required=False)
        return cls(
            profile=profile,
            form=form,
            sweep_geometry=geometry,
            inputs=inputs,
            outputs=outputs,
            input_shape=input_shape,
            state_shape=state,
            polar_input=polar,
            masking=meta.get("radar_odom.masking", "unknown"),
            training_data=meta.get("radar_odom.training_data", ""),
            version=meta.get("radar_odom.version", ""),
            opset=int(opset) if opset else None,
            exporter=meta.get("radar_odom.exporter", ""),
            source=source,
            search=search,
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
            raise ModelNotFoundError(
                f"{self.path}: no such model file; give a path to an exported .onnx or a name from "
                "radar_odom.pretrained_names()"
            )
        try:
            self.session = ort.InferenceSession(
                str(self.path),
                sess_options=session_options(threads, enable_profiling, profile_prefix),
                providers=list(providers) if providers else ["CPUExecutionProvider"],
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
        ins = {i.name: i for i in self.session.get_inputs()}
        outs = {o.name: o for o in self.session.get_outputs()}
        names_in = tuple(i.name for i in self.session.get_inputs())
        if names_in != self.info.inputs:
            raise InvalidModelError(f"{self.path}: graph inputs {names_in} differ from metadata {self.info.inputs}")
        if not {"pose", "covariance"} <= set(outs) or (self.info.form == "stream" and "state" not in outs):
            raise InvalidModelError(
                f"{self.path}: graph outputs {tuple(outs)} lack "
                f"{'pose/covariance/state' if self.info.form == 'stream' else 'pose/covariance'}"
            )
        expect = {self.info.inputs[0]: self.info.input_shape}
        if self.info.form == "stream":
            expect[self.info.inputs[1]] = self.info.state_shape
        else:
            expect[self.info.inputs[1]] = self.info.input_shape
        for name, want in expect.items():
            self._check_shape("input", name, ins[name], want)
        if self.info.form == "stream":
            self._check_shape("output", "state", outs["state"], self.info.state_shape)
        self._check_shape("output", "pose", outs["pose"], None, size=3)
        self._check_shape("output", "covariance", outs["covariance"], None, size=9)
        self.output_names = list(outs)

    def _check_shape(self, kind: str, name: str, arg, want, size: int | None = None) -> None:
        shape = list(arg.shape)
        if arg.type != "tensor(float)":
            raise InvalidModelError(f"{self.path}: graph {kind} {name!r} is {arg.type}, expected tensor(float)")
        fixed = all(isinstance(d, int) for d in shape)
        if want is not None and (len(shape) != len(want) or any(
                isinstance(d, int) and d != w for d, w in zip(shape, want))):
            raise InvalidModelError(
                f"{self.path}: graph {kind} {name!r} has shape {shape} but the metadata says {list(want)}; "
                "the metadata was edited or belongs to another graph — re-export the model"
            )
        if size is not None and fixed and int(np.prod(shape)) != size:
            raise InvalidModelError(f"{self.path}: graph {kind} {name!r} has shape {shape}, expected {size} values")

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
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
