"""The radar-odom model file: what an exported ONNX file promises, in one place.

The exporter (``radar_odom_export.onnx_export``) writes every fact the runtime needs into the
file's ``metadata_props`` under ``radar_odom.*`` keys with `build_metadata`; the runtime reads
them back with `ModelInfo.from_metadata` and holds the graph onnxruntime loaded to them with
`check_signature`. Writer and reader share this module, so nothing about a model is re-typed.

The keys (`SCHEMA`; required: always, or for stream-form / polar models only):

- ``radar_odom.format`` (text, required): `FORMAT`.
- ``radar_odom.profile`` (JSON object, required): the `GridProfile` (`GridProfile.to_metadata`).
- ``radar_odom.form`` (text, required): ``"stream"`` (inputs: current sweep + previous state;
  outputs: pose, covariance, state), ``"pair"`` (inputs: previous and current sweep; outputs:
  pose, covariance) or ``"sequence"`` (input: T consecutive sweeps, T free in the file, at least
  2; outputs: pose [T − 1, 3] and covariance [T − 1, 3, 3], one per consecutive pair: the
  offline batch form, ``radar_odom.odometry.batch``) or ``"sweep"`` (the self-contained form of a
  Cartesian stream graph, for consumers outside Python: inputs ``power`` [A, B] float32 in [0, 1]
  as recorded, ``azimuths_rad`` [A], ``range_resolution_m`` [1], ``range_offset_m`` [1] and
  ``prev_state``; the polar→Cartesian drawing inside; outputs those of the stream form; A and B
  are free in the file, docs/sweep-form.md).
- ``radar_odom.sweep_geometry`` (JSON object, required): ``{num_azimuths, num_bins,
  range_resolution_m, range_offset_m}`` of the sweeps the model was trained on.
- ``radar_odom.inputs`` / ``radar_odom.outputs`` (JSON arrays, required): tensor names, in
  graph order.
- ``radar_odom.input_shape`` (JSON array, required): shape of one sweep input (``[1, W, W]``
  Cartesian or ``[1, A, B']`` polar; the sequence form's input is T of them along axis 0; the
  sweep form's: ``[A, B]`` of the sweep geometry, free in the graph).
- ``radar_odom.state_shape`` (JSON array, required for the stream and sweep forms): shape of the stream
  state (single mode: the half spectrum ``[1, 2, W, W//2 + 1]``; dual mode: the sweep input's).
- ``radar_odom.polar_input`` (JSON object, required for polar models): ``{num_bins,
  bin_factor}``, how the polar sweep is reduced before the graph.
- ``radar_odom.profile_sha256`` (hex): SHA-256 of the profile text (`profile_digest`); when
  present, a profile edited by hand is refused.
- ``radar_odom.search`` (JSON object): which search the graph runs and its settings: ``kind``
  ``coarse_to_fine`` (``fast_search``) or ``decoupled`` (``decoupled_search``: yaw from the
  magnitude spectra, then one translation correlation); absent when every yaw candidate is scored.
- ``radar_odom.quantization`` (JSON object): how the masker's ``Conv`` nodes were quantised
  (``radar_odom_export.quantize``: scheme, op types, weight/activation types, calibration);
  absent for a float32 graph.
- ``radar_odom.mount_yaw_rad`` (number): the radar's yaw on its vehicle (rad, the poses' sign
  convention), found by ``radar-odom adapt``; the runtime turns every match by it
  (`radar_odom.se2.turn_frame`), so poses are the vehicle's. Absent: 0 (the radar looks along the
  vehicle's axis; every shipped model).
- provenance, optional (a file without them reads the `MetadataKey.default` stated below):
  ``radar_odom.masking``, ``radar_odom.training_data``, ``radar_odom.version``,
  ``radar_odom.opset``, ``radar_odom.exporter``, ``radar_odom.torch_version``.

Validation: a missing required key, text that is not JSON, a value of the wrong type or out of
range, a profile inconsistent with the sweep input's shape (e.g. ``width_px`` against
``[1, W, W]``) or with its digest → `InvalidModelError` (a `ModelMismatchError`) naming the
key. `check_signature` then holds the graph's real inputs and outputs (names, shapes, float
tensors) to the metadata, and the stream state's shape to the profile (`check_state_shape`).
A scale change that keeps every shape (``resolution_m`` edited together with its digest)
cannot be detected from the file.

This module imports neither torch nor onnxruntime.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import MISSING, dataclass, fields

from .errors import InvalidModelError, ModelMismatchError
from .profiles import GridProfile

FORMAT = "radar-odom-onnx/1"
FORMS = ("stream", "pair", "sequence", "sweep")
STATE_FORMS = ("stream", "sweep")  # the forms that take and return a stream state
# the sweep form's inputs besides ``prev_state``, in graph order (docs/sweep-form.md)
SWEEP_INPUTS = ("power", "azimuths_rad", "range_resolution_m", "range_offset_m")
# the sweep form's bearing table: equal bins over the turn; its drawing is exact where no bin holds two azimuths
# (azimuths more than 360°/2048 = 0.18° apart; a Navtech sweep's 400 rows are 0.9° apart; docs/sweep-form.md)
SWEEP_TABLE_BINS = 2048
DEFAULT_OPSET = 18  # the ONNX opset exports write unless asked for another (CLI ``--opset``)
# the lowest opset an export reaches: torch's dynamo exporter writes 18 and converts down with onnx's version
# converter, which has no adapter for Pad below 18 (`radar-odom export cart-0.8 --opset 17` fails so)
MIN_EXPORT_OPSET = 18


@dataclass(frozen=True)
class MetadataKey:
    """One ``radar_odom.*`` metadata entry: its type, when it is required, what it means."""

    key: str
    kind: str  # "text", "json-object", "json-array", "integer" / "number" (as text), "sha256"
    required: str  # "always", "stream" (stream form), "polar" (polar input), "optional"
    doc: str
    default: object = None  # what a file without an optional key reads as


SCHEMA: tuple[MetadataKey, ...] = (
    MetadataKey("radar_odom.format", "text", "always", f"the file format, {FORMAT!r}"),
    MetadataKey("radar_odom.profile", "json-object", "always", "the GridProfile"),
    MetadataKey("radar_odom.form", "text", "always", "'stream', 'pair', 'sequence' or 'sweep'"),
    MetadataKey("radar_odom.sweep_geometry", "json-object", "always", "geometry of the training sweeps"),
    MetadataKey("radar_odom.inputs", "json-array", "always", "input tensor names, in graph order"),
    MetadataKey("radar_odom.outputs", "json-array", "always", "output tensor names, in graph order"),
    MetadataKey("radar_odom.input_shape", "json-array", "always", "shape of one sweep input"),
    MetadataKey("radar_odom.state_shape", "json-array", "stream", "shape of the stream state (stream, sweep)"),
    MetadataKey("radar_odom.polar_input", "json-object", "polar", "{num_bins, bin_factor} of a polar input"),
    MetadataKey("radar_odom.profile_sha256", "sha256", "optional", "SHA-256 of the profile text"),
    MetadataKey("radar_odom.search", "json-object", "optional",
                "the search and its settings (kind coarse_to_fine or decoupled); absent: every yaw candidate "
                "is scored"),
    MetadataKey("radar_odom.quantization", "json-object", "optional",
                "int8 quantisation of the masker (scheme, op types, calibration); absent: float32"),
    MetadataKey("radar_odom.mount_yaw_rad", "number", "optional",
                "the radar's yaw on its vehicle (rad); matches are turned by it", "0"),
    MetadataKey("radar_odom.masking", "text", "optional", "masking of the model", "unknown"),
    MetadataKey("radar_odom.training_data", "text", "optional", "JSON provenance of the weights", ""),
    MetadataKey("radar_odom.version", "text", "optional", "radar-odom version that exported it", ""),
    MetadataKey("radar_odom.opset", "integer", "optional", "ONNX opset written"),
    MetadataKey("radar_odom.exporter", "text", "optional", "'dynamo' or 'torchscript'", ""),
    MetadataKey("radar_odom.torch_version", "text", "optional", "torch version of the export", ""),
)
KEYS = {k.key: k for k in SCHEMA}
REQUIRED_KEYS = tuple(k.key for k in SCHEMA if k.required == "always")
GEOMETRY_KEYS = ("num_azimuths", "num_bins", "range_resolution_m", "range_offset_m")
MAX_ROTATIONS = 7201  # candidates; a 0.05° step over ±180°


def profile_digest(profile_text: str) -> str:
    """SHA-256 hex of the ``radar_odom.profile`` metadata text (``radar_odom.profile_sha256``)."""
    return hashlib.sha256(profile_text.encode("utf-8")).hexdigest()


def expected_input_shape(profile: GridProfile, geometry: dict, polar_input: dict | None,
                         form: str = "stream") -> tuple[int, ...]:
    """The sweep input's shape that follows from the profile: ``(1, W, W)``, or ``(1, A, B')``;
    the sweep form's raw power ``(A, B)`` of the sweep geometry."""
    if form == "sweep":
        return (int(geometry["num_azimuths"]), int(geometry["num_bins"]))
    if profile.input_kind == "polar":
        return (1, int(geometry["num_azimuths"]), int(polar_input["num_bins"]))
    return (1, profile.width_px, profile.width_px)


def expected_state_shape(profile: GridProfile, input_shape: tuple[int, ...]) -> tuple[int, ...]:
    """The stream state's shape: the half spectrum (single mode) or the previous sweep (dual)."""
    if profile.mode == "dual":
        return tuple(input_shape)
    return (1, 2, profile.width_px, profile.width_px // 2 + 1)


_TYPE_NAMES = {dict: "object", list: "array", str: "string"}
# GridProfile fields whose range its own checks leave open (a negative window, a zero step...)
_PROFILE_RANGES = {
    "max_translation_m": (0.0, False), "rotation_range_rad": (0.0, False),
    "rotation_step_rad": (0.0, True), "beta_pose": (0.0, True), "beta_cov": (0.0, True),
    "near_range_m": (0.0, False), "unet_base_channels": (1, False), "unet_depth": (0, False),
    "cov_floor_cells": (0.0, False), "cov_floor_yaw_cells": (0.0, False), "cov_scale": (0.0, True),
    "pose_window_cells": (0, False),
}


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

    def integer(self, key: str) -> int | None:
        text = self.meta.get(key)
        if text is None:
            return KEYS[key].default
        t = text.strip()
        if not (t.isascii() and t.isdigit() and len(t) < 7):
            self.fail(key, f"is {text[:40]!r}, not an integer")
        return int(t)

    def number(self, key: str, low: float, high: float) -> float | None:
        """A finite number in [low, high], or None where the key is absent."""
        text = self.meta.get(key)
        if text is None:
            return None
        try:
            value = float(text)
        except ValueError:
            self.fail(key, f"is {text[:40]!r}, not a number")
        if not (math.isfinite(value) and low <= value <= high):
            self.fail(key, f"is {value!r}, outside [{low:.4g}, {high:.4g}]")
        return value

    def text(self, key: str) -> str:
        return self.meta.get(key, KEYS[key].default)

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
    search: dict | None = None  # fast/decoupled search settings ("kind"); None: every yaw candidate is scored
    torch_version: str = ""
    quantization: dict | None = None  # int8 masker settings; None: a float32 graph
    mount_yaw_rad: float = 0.0  # the radar's yaw on its vehicle (`radar-odom adapt`); 0: along the axis

    @classmethod
    def from_metadata(cls, meta: dict[str, str], source: str = "model") -> ModelInfo:
        """Parse and validate ``radar_odom.*`` metadata.

        Raises `ModelMismatchError` if it is not a radar-odom model at all, `InvalidModelError`
        (naming the key) if a required key is missing, not JSON, of the wrong type, out of range
        or inconsistent with another (see the module docstring).
        """
        if not isinstance(meta, dict):
            raise InvalidModelError(f"{source}: metadata must be a dict of strings, got {type(meta).__name__}")
        if meta.get("radar_odom.format") != FORMAT:
            raise ModelMismatchError(
                f"{source}: not a radar-odom model (metadata 'radar_odom.format' is "
                f"{meta.get('radar_odom.format')!r}, expected {FORMAT!r}); export one with "
                "`radar-odom export model.pt`"
            )
        # a radar-odom file without its profile is a damaged one, not a foreign one: the missing-key
        # check below names it (folded into the format check, it read "is 'radar-odom-onnx/1', expected
        # 'radar-odom-onnx/1'")
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
        if form not in FORMS:
            raise InvalidModelError(f"{source}: metadata 'radar_odom.form' is {form!r}, not one of {', '.join(FORMS)}")
        profile = v.profile()
        geometry = v.json("radar_odom.sweep_geometry", dict)
        for k in ("num_azimuths", "num_bins"):
            v.check_int(geometry, k, "radar_odom.sweep_geometry", low=2)
        v.check_float(geometry, "range_resolution_m", "radar_odom.sweep_geometry", low=0.0, open_low=True)
        v.check_float(geometry, "range_offset_m", "radar_odom.sweep_geometry")
        inputs = v.names("radar_odom.inputs", {"sequence": 1, "sweep": len(SWEEP_INPUTS) + 1}.get(form, 2))
        outputs = v.names("radar_odom.outputs", None)
        if form == "sweep" and (profile.input_kind != "cartesian" or inputs[:-1] != SWEEP_INPUTS):
            raise InvalidModelError(
                f"{source}: a sweep-form model draws a Cartesian image from inputs {list(SWEEP_INPUTS)} + prev_state; "
                f"this one has {profile.input_kind} input and inputs {list(inputs)} — re-export it")
        for need in ("pose", "covariance") + (("state",) if form in STATE_FORMS else ()):
            if need not in outputs:
                raise InvalidModelError(f"{source}: metadata 'radar_odom.outputs' {outputs} lacks {need!r}")
        input_shape = v.shape("radar_odom.input_shape")
        state = v.shape("radar_odom.state_shape", required=form in STATE_FORMS)
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
        want = expected_input_shape(profile, geometry, polar, form)
        if input_shape != want:
            raise InvalidModelError(
                f"{source}: metadata 'radar_odom.input_shape' {list(input_shape)} does not match the "
                f"profile ({list(want)} for {profile.input_kind} input, width_px {profile.width_px}); "
                "the metadata was edited — re-export the model"
            )
        opset = v.integer("radar_odom.opset")
        search = v.json("radar_odom.search", dict, required=False)
        quantization = v.json("radar_odom.quantization", dict, required=False)
        mount_yaw = v.number("radar_odom.mount_yaw_rad", low=-math.pi / 4, high=math.pi / 4)
        return cls(
            profile=profile,
            form=form,
            sweep_geometry=geometry,
            inputs=inputs,
            outputs=outputs,
            input_shape=input_shape,
            state_shape=state,
            polar_input=polar,
            masking=v.text("radar_odom.masking"),
            training_data=v.text("radar_odom.training_data"),
            version=v.text("radar_odom.version"),
            opset=opset,
            exporter=v.text("radar_odom.exporter"),
            source=source,
            search=search,
            torch_version=v.text("radar_odom.torch_version"),
            quantization=quantization,
            mount_yaw_rad=0.0 if mount_yaw is None else mount_yaw,
        )

    @property
    def sweep_input(self) -> str:
        """Name of the current-sweep input (``cart`` or ``polar``; ``power`` in the sweep form)."""
        if self.form == "sweep":
            return "power"
        return "polar" if self.profile.input_kind == "polar" else "cart"


def io_names(profile: GridProfile, form: str) -> tuple[list[str], list[str]]:
    """(input names, output names) of a graph of ``form`` for ``profile``, in graph order."""
    sweep = "polar" if profile.input_kind == "polar" else "cart"
    if form == "stream":
        return [sweep, "prev_state"], ["pose", "covariance", "state"]
    if form == "pair":
        return [f"prev_{sweep}", sweep], ["pose", "covariance"]
    if form == "sequence":
        return [f"{sweep}s"], ["pose", "covariance"]
    if form == "sweep":
        return [*SWEEP_INPUTS, "prev_state"], ["pose", "covariance", "state"]
    raise ValueError(f"form must be one of {FORMS}, got {form!r}")


def build_metadata(*, profile: GridProfile, form: str, sweep_geometry: dict, input_shape, state_shape=None,
                   polar_input: dict | None = None, masking: str, training_data="", version: str,
                   opset: int, exporter: str, torch_version: str = "", search: dict | None = None,
                   quantization: dict | None = None, mount_yaw_rad: float | None = None,
                   source: str = "export") -> dict[str, str]:
    """The ``radar_odom.*`` metadata of a model file, as text, checked by `ModelInfo.from_metadata`
    (so the writer can never write what the runtime refuses: `InvalidModelError` if it would).

    ``training_data``: text, or a JSON-able dict; ``search``: the fast search's settings;
    ``quantization``: how the masker was quantised (``radar_odom_export.quantize``).
    """
    inputs, outputs = io_names(profile, form)
    meta = {
        "radar_odom.format": FORMAT,
        **profile.to_metadata(),
        "radar_odom.form": form,
        "radar_odom.sweep_geometry": json.dumps(sweep_geometry, sort_keys=True),
        "radar_odom.inputs": json.dumps(inputs),
        "radar_odom.outputs": json.dumps(outputs),
        "radar_odom.input_shape": json.dumps([int(d) for d in input_shape]),
        "radar_odom.masking": masking,
        "radar_odom.training_data": training_data if isinstance(training_data, str)
        else json.dumps(training_data or {}, sort_keys=True, default=str),
        "radar_odom.version": version,
        "radar_odom.opset": str(int(opset)),
        "radar_odom.exporter": exporter,
        "radar_odom.torch_version": torch_version,
    }
    if state_shape is not None:
        meta["radar_odom.state_shape"] = json.dumps([int(d) for d in state_shape])
    if polar_input is not None:
        meta["radar_odom.polar_input"] = json.dumps(polar_input)
    # a digest of the profile text: the runtime refuses a profile edited by hand (a changed
    # resolution_m keeps every tensor shape, so nothing else would notice)
    meta["radar_odom.profile_sha256"] = profile_digest(meta["radar_odom.profile"])
    if search is not None:
        meta["radar_odom.search"] = json.dumps(search, sort_keys=True)
    if quantization is not None:
        meta["radar_odom.quantization"] = json.dumps(quantization, sort_keys=True)
    if mount_yaw_rad is not None:
        meta["radar_odom.mount_yaw_rad"] = repr(float(mount_yaw_rad))
    unknown = sorted(set(meta) - set(KEYS))
    if unknown:  # a key added to the writer must be added to the schema first
        raise ValueError(f"metadata keys {unknown} are not in model_file.SCHEMA")
    check_state_shape(ModelInfo.from_metadata(meta, source=source))
    return meta


def check_state_shape(info: ModelInfo) -> None:
    """The stream state's shape must be the one the profile implies (`expected_state_shape`; the sweep
    form's is its inner stream graph's, of the Cartesian image)."""
    if info.form not in STATE_FORMS:
        return
    image = info.input_shape if info.form == "stream" else expected_input_shape(info.profile, info.sweep_geometry, None)
    want = expected_state_shape(info.profile, image)
    if info.state_shape != want:
        raise InvalidModelError(
            f"{info.source}: metadata 'radar_odom.state_shape' {list(info.state_shape)} does not match the "
            f"profile ({list(want)} for {info.profile.mode} mode, width_px {info.profile.width_px}); "
            "the metadata was edited — re-export the model"
        )


def check_signature(info: ModelInfo, inputs, outputs, source: str = "model") -> None:
    """Hold a graph's real inputs and outputs to its metadata; `InvalidModelError` if they differ.

    ``inputs`` / ``outputs``: sequences of ``(name, shape, type)`` in graph order, as onnxruntime
    reports them (``[(a.name, a.shape, a.type) for a in session.get_inputs()]``; a dimension may
    be a string for a symbolic size, ``type`` is e.g. ``"tensor(float)"``).
    """
    ins = {name: (list(shape), kind) for name, shape, kind in inputs}
    outs = {name: (list(shape), kind) for name, shape, kind in outputs}
    names_in = tuple(name for name, _, _ in inputs)
    if names_in != info.inputs:
        raise InvalidModelError(f"{source}: graph inputs {names_in} differ from metadata {info.inputs}")
    stateful = info.form in STATE_FORMS
    if not {"pose", "covariance"} <= set(outs) or (stateful and "state" not in outs):
        raise InvalidModelError(
            f"{source}: graph outputs {tuple(outs)} lack "
            f"{'pose/covariance/state' if stateful else 'pose/covariance'}"
        )
    expect = {info.inputs[0]: info.input_shape}
    if info.form == "sequence":
        shape = ins[info.inputs[0]][0]
        if shape and isinstance(shape[0], int):
            raise InvalidModelError(
                f"{source}: graph input {info.inputs[0]!r} has a fixed sweep count {shape[0]}; a sequence-form "
                "model takes any number of sweeps along axis 0 — re-export it with `radar-odom export --form sequence`"
            )
    elif info.form == "sweep":  # power [A, B] (free in the graph), azimuths [A], two scalars [1], the state
        a = info.input_shape[0]
        expect.update({"azimuths_rad": (a,), "range_resolution_m": (1,), "range_offset_m": (1,),
                       "prev_state": info.state_shape})
    else:
        expect[info.inputs[1]] = info.state_shape if info.form == "stream" else info.input_shape
    for name, want in expect.items():
        _check_shape(source, "input", name, *ins[name], want)
    if stateful:
        _check_shape(source, "output", "state", *outs["state"], info.state_shape)
    _check_shape(source, "output", "pose", *outs["pose"], None, size=3)
    _check_shape(source, "output", "covariance", *outs["covariance"], None, size=9)
    check_state_shape(info)  # graph and metadata agree; both must agree with the profile too


def _check_shape(source: str, kind: str, name: str, shape: list, type_name: str, want, size: int | None = None):
    if type_name != "tensor(float)":
        raise InvalidModelError(f"{source}: graph {kind} {name!r} is {type_name}, expected tensor(float)")
    if want is not None and (len(shape) != len(want) or any(
            isinstance(d, int) and d != w for d, w in zip(shape, want))):
        raise InvalidModelError(
            f"{source}: graph {kind} {name!r} has shape {shape} but the metadata says {list(want)}; "
            "the metadata was edited or belongs to another graph — re-export the model"
        )
    if size is not None and all(isinstance(d, int) for d in shape) and math.prod(shape) != size:
        raise InvalidModelError(f"{source}: graph {kind} {name!r} has shape {shape}, expected {size} values")
