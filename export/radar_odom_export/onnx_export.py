"""Export a `MaskedCorrelator` to one self-contained ONNX file the runtime configures itself from.

What ends up in the file (``radar-odom export model.pt``):

* the whole step in one graph: the input normalisation (profile ``input_norm``, see
  `normalise`), masker (U-Net, or the CFAR mask of ``masking="cfar"``), polar→Cartesian for
  polar models, rotation by every yaw candidate (``GridSample``), the matmul DFT (no
  ``DFT``/``STFT`` op anywhere: those run only on onnxruntime's CPU provider), the windowed
  inverse, and the soft-argmax;
* **stream form** (default): inputs ``cart`` [1, W, W] (``polar`` [1, A, B'] for polar models)
  and ``prev_state`` (single mode: the previous masked sweep's half spectrum [1, 2, W, W/2+1];
  dual mode: the previous sweep), outputs ``pose`` [1, 3], ``covariance`` [1, 3, 3] and
  ``state``; **pair form**: inputs ``prev_cart``, ``cart`` (``prev_polar``, ``polar``),
  outputs ``pose``, ``covariance``;
* ``metadata_props`` (see `radar_odom.onnx_model`): profile, form, sweep geometry, names and
  shapes, masking, training data, versions.

Rotation grids: K sampling grids of W×W×2 floats would be 126 MB at 0.2 m/px, so the exported
rotator computes them inside the graph from the K yaw values (`InGraphRotator`, the same
formula as training's precomputed grids); onnxruntime folds them once at session start.

Exporter: ``torch.onnx.export(dynamo=True)`` (torch.export + onnxscript) is used first — it keeps
the in-graph grid computation as a handful of nodes. If it fails, the TorchScript exporter
(``dynamo=False``) is the fallback; it folds the grids into constants, so the size check may then
refuse large profiles. The chosen exporter is recorded in the metadata.

After writing, the file is checked (`check_onnx_file`): opset equals the requested one, one
file (no external data), at most `MAX_BYTES`, ``onnx.checker`` full check, no DFT/STFT node in
the graph, its subgraphs or functions.
"""
from __future__ import annotations

import copy
import json
import os
import tempfile
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

import radar_odom
from radar_odom.errors import ExportError, RadarOdomError
from radar_odom.onnx_model import FORMAT, ModelInfo, profile_digest

from .correlation import Rotator, make_correlation, rotate_images, rotation_grids

DEFAULT_OPSET = 18
MAX_BYTES = 20 * 1024 * 1024
FORBIDDEN_OPS = frozenset({"DFT", "STFT"})


class ExportError(RadarOdomError, RuntimeError):
    """The exported file breaks a promise (opset, size, forbidden ops, checker)."""


# ----------------------------------------------------------------------------- graph modules
class InGraphRotator(nn.Module):
    """`Rotator` whose sampling grids are computed in the forward pass from the yaw values.

    Same yaw order, the same exact identity slice for yaw 0, the same grid formula
    (`rotation_grids`): only where the grids come from differs, so the file stores K floats
    instead of K·W·W·2.
    """

    def __init__(self, rotator: Rotator, rotations_rad, width_px: int):
        super().__init__()
        self.zero_index = rotator.zero_index
        self.width_px = width_px
        others = [y for y in rotations_rad if y != 0.0]
        # float64 → float32 once, as the training grids are built (float64 grid, float32 stored)
        self.register_buffer("yaws", torch.tensor(others, dtype=torch.float32), persistent=False)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        grids = rotation_grids(self.yaws, self.width_px)
        rotated = rotate_images(images, grids)
        z = self.zero_index
        return torch.cat([rotated[:, :z], images.unsqueeze(1), rotated[:, z:]], dim=1)


class StreamGraph(nn.Module):
    """(sweep, prev_state) → (pose, covariance, state): `MaskedCorrelator.stream_step`."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, sweep, prev_state):
        return self.model.stream_step(sweep, prev_state)


class PairGraph(nn.Module):
    """(prev_sweep, sweep) → (pose, covariance): `MaskedCorrelator.forward`."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, prev_sweep, sweep):
        return self.model(prev_sweep, sweep)


def exportable(model) -> nn.Module:
    """A copy of ``model`` with the matmul-DFT correlation and in-graph rotation grids, in eval mode."""
    m = copy.deepcopy(model).cpu().eval()
    p = m.profile
    m.correlation = make_correlation("matmul", p.width_px, p.translation_cells)
    m.rotator = InGraphRotator(m.rotator, p.rotations_rad, p.width_px)
    m.dft = "matmul"
    return m


def sweep_shape(model) -> tuple[int, ...]:
    """Shape of one sweep input: (1, W, W), or (1, A, B') for a polar model."""
    if model.to_cartesian is not None:
        return (1, *model.to_cartesian.input_shape)
    return (1, model.profile.width_px, model.profile.width_px)


def io_names(model, form: str) -> tuple[list[str], list[str]]:
    sweep = "polar" if model.profile.input_kind == "polar" else "cart"
    if form == "stream":
        return [sweep, "prev_state"], ["pose", "covariance", "state"]
    return [f"prev_{sweep}", sweep], ["pose", "covariance"]


def example_inputs(model, form: str, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Plausible inputs (random sparse power in [0, 1]) for tracing and checks."""
    g = torch.Generator().manual_seed(seed)
    shape = sweep_shape(model)
    prev = torch.rand(shape, generator=g) ** 8  # mostly dark with bright returns, like radar
    cur = torch.rand(shape, generator=g) ** 8
    if form == "pair":
        return prev, cur
    with torch.no_grad():
        state = model.initial_state(prev)
    return cur, state


# ----------------------------------------------------------------------------- checks
def walk_nodes(nodes):
    """Every node of a node list (a graph's or a function's), descending into subgraphs
    (If/Loop/Scan bodies) at any depth."""
    import onnx

    for node in nodes:
        yield node
        for attr in node.attribute:
            if attr.type == onnx.AttributeProto.GRAPH:
                yield from walk_nodes(attr.g.node)
            elif attr.type == onnx.AttributeProto.GRAPHS:
                for g in attr.graphs:
                    yield from walk_nodes(g.node)


def op_counts(model_proto) -> Counter:
    """Node count per op type over the main graph, its subgraphs and all local functions."""
    counts = Counter(n.op_type for n in walk_nodes(model_proto.graph.node))
    for fn in model_proto.functions:
        counts.update(n.op_type for n in walk_nodes(fn.node))
    return counts


def onnx_opset(model_proto) -> int:
    """The default-domain opset the file declares."""
    for o in model_proto.opset_import:
        if o.domain in ("", "ai.onnx"):
            return int(o.version)
    raise ExportError("the file declares no default-domain opset")


def check_onnx_file(path, opset: int = DEFAULT_OPSET, max_bytes: int = MAX_BYTES) -> dict:
    """Check the promises of an exported file; raise `ExportError` naming the broken one.

    Returns ``{"bytes", "opset", "ops": Counter}``.
    """
    import onnx

    path = Path(path)
    size = path.stat().st_size
    if size > max_bytes:
        raise ExportError(f"{path}: {size / 2**20:.1f} MiB exceeds the {max_bytes / 2**20:.0f} MiB budget")
    proto = onnx.load(str(path), load_external_data=False)
    external = [t.name for t in proto.graph.initializer if t.data_location == onnx.TensorProto.EXTERNAL]
    if external:
        raise ExportError(f"{path}: initializers {external[:3]} live in external files; the file must be self-contained")
    got = onnx_opset(proto)
    if got != opset:
        raise ExportError(f"{path}: written at opset {got}, but opset {opset} was requested "
                          "(the exporter could not reach it); choose --opset {got} or check the exporter")
    ops = op_counts(proto)
    bad = sorted(FORBIDDEN_OPS & set(ops))
    if bad:
        raise ExportError(f"{path}: graph holds {bad} nodes, which CUDA/TensorRT and edge runtimes lack")
    try:
        onnx.checker.check_model(str(path), full_check=True)
    except onnx.checker.ValidationError as exc:
        raise ExportError(f"{path}: onnx.checker (full check) refuses the file: {exc}") from None
    return {"bytes": size, "opset": got, "ops": ops}


# ----------------------------------------------------------------------------- export
@dataclass
class ExportReport:
    """What `export_model` wrote and measured."""

    path: Path
    form: str
    exporter: str
    opset: int
    bytes: int
    ops: Counter
    metadata: dict
    seconds: float
    max_pose_diff: float | None = None  # |ORT − torch| on random inputs, when verified
    notes: list = field(default_factory=list)

    def summary(self) -> str:
        prof = json.loads(self.metadata["radar_odom.profile"])
        lines = [
            f"wrote {self.path} ({self.bytes / 2**20:.2f} MiB, opset {self.opset}, {self.form} form, "
            f"exporter {self.exporter}, {self.seconds:.1f} s)",
            f"profile {prof['name']}: {prof['resolution_m']} m/px, {prof['width_px']} px, "
            f"inputs {json.loads(self.metadata['radar_odom.inputs'])} -> "
            f"{json.loads(self.metadata['radar_odom.outputs'])}",
            f"nodes: {sum(self.ops.values())} ({', '.join(f'{k} {v}' for k, v in self.ops.most_common(6))}, ...)",
        ]
        if self.max_pose_diff is not None:
            lines.append(f"check: onnxruntime vs torch max |Δpose| = {self.max_pose_diff:.2e}")
        lines += self.notes
        return "\n".join(lines)


def strip_node_metadata(proto) -> int:
    """Delete every node's ``metadata_props`` (the dynamo exporter's per-node stack traces, FX
    names and scopes) in the graph, its subgraphs and local functions; returns how many entries
    went. They hold the build machine's file paths and source lines and are a third of a shipped
    file's metadata; nothing reads them at run time."""
    removed = 0
    graphs = [proto.graph] + [f for f in proto.functions]
    for node in walk_nodes([n for g in graphs for n in g.node]):
        removed += len(node.metadata_props)
        del node.metadata_props[:]
    for f in proto.functions:
        del f.metadata_props[:]
    del proto.graph.metadata_props[:]
    return removed


def build_metadata(model, form: str, opset: int, exporter: str, masking: str, training_data, state_shape) -> dict:
    """The ``radar_odom.*`` metadata (see `radar_odom.onnx_model`) for ``model``."""
    inputs, outputs = io_names(model, form)
    meta = {
        "radar_odom.format": FORMAT,
        **model.profile.to_metadata(),
        "radar_odom.form": form,
        "radar_odom.sweep_geometry": json.dumps(model.sweep_geometry, sort_keys=True),
        "radar_odom.inputs": json.dumps(inputs),
        "radar_odom.outputs": json.dumps(outputs),
        "radar_odom.input_shape": json.dumps(list(sweep_shape(model))),
        "radar_odom.masking": masking,
        "radar_odom.training_data": training_data if isinstance(training_data, str)
        else json.dumps(training_data or {}, sort_keys=True, default=str),
        "radar_odom.version": radar_odom.__version__,
        "radar_odom.opset": str(opset),
        "radar_odom.exporter": exporter,
        "radar_odom.torch_version": torch.__version__,
    }
    if state_shape is not None:
        meta["radar_odom.state_shape"] = json.dumps(list(state_shape))
    if model.to_cartesian is not None:
        meta["radar_odom.polar_input"] = json.dumps(
            {"num_bins": model.to_cartesian.num_bins, "bin_factor": model.to_cartesian.bin_factor}
        )
    # a digest of the profile text: the runtime refuses a profile edited by hand (a changed
    # resolution_m keeps every tensor shape, so nothing else would notice)
    meta["radar_odom.profile_sha256"] = profile_digest(meta["radar_odom.profile"])
    # the runtime's schema (required keys, types, ranges, profile vs input shape) checks what is written
    try:
        ModelInfo.from_metadata(meta, source="export")
    except RadarOdomError as exc:
        raise ExportError(f"the metadata for this model would be refused at run time: {exc}") from None
    return meta


def _torch_export(module, inputs, path, input_names, output_names, opset, dynamo: bool):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporters' deprecation chatter is not for users
        kwargs = dict(input_names=input_names, output_names=output_names, opset_version=opset,
                      dynamo=dynamo, external_data=False)
        if dynamo:
            kwargs["verbose"] = False
        else:
            kwargs["do_constant_folding"] = True
        torch.onnx.export(module, inputs, str(path), **kwargs)


def export_model(model, path, *, form: str = "stream", opset: int = DEFAULT_OPSET, masking: str | None = None,
                 training_data=None, exporter: str = "auto", verify: bool = True) -> ExportReport:
    """Export a `MaskedCorrelator` (any DFT backend) to ``path``; check and describe the file.

    ``exporter``: ``"auto"`` (dynamo, falling back to TorchScript), ``"dynamo"`` or
    ``"torchscript"``. ``verify`` runs the file in onnxruntime against the torch model on random
    inputs and records the largest pose difference.
    """
    import onnx

    if form not in ("stream", "pair"):
        raise ValueError(f"form must be 'stream' or 'pair', got {form!r}")
    t0 = time.perf_counter()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    m = exportable(model)
    module = StreamGraph(m) if form == "stream" else PairGraph(m)
    inputs = example_inputs(m, form)
    input_names, output_names = io_names(m, form)
    notes = []
    tried = ["dynamo", "torchscript"] if exporter == "auto" else [exporter]
    used, errors = None, []
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "graph.onnx"
        for kind in tried:
            try:
                with torch.no_grad():
                    _torch_export(module, inputs, raw, input_names, output_names, opset, dynamo=(kind == "dynamo"))
                used = kind
                break
            except Exception as exc:  # noqa: BLE001 - any exporter failure means: try the next one
                errors.append(f"{kind}: {type(exc).__name__}: {str(exc).splitlines()[0][:300] if str(exc) else ''}")
        if used is None:
            raise ExportError("every exporter failed:\n" + "\n".join(errors))
        if errors:
            notes.append("fell back from " + "; ".join(errors))
        proto = onnx.load(str(raw))
    state_shape = None
    if form == "stream":
        state_shape = tuple(inputs[1].shape)
    meta = build_metadata(m, form, opset, used, masking or m.masking, training_data, state_shape)
    strip_node_metadata(proto)
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    proto.doc_string = (f"radar-odom {radar_odom.__version__}: Masking by Moving radar odometry, "
                        f"profile {m.profile.name}, {form} form")
    onnx.save(proto, str(path))
    checked = check_onnx_file(path, opset)
    report = ExportReport(path, form, used, checked["opset"], checked["bytes"], checked["ops"], meta,
                          time.perf_counter() - t0, notes=notes)
    if verify:
        report.max_pose_diff = verify_against_torch(path, model, form)
        report.seconds = time.perf_counter() - t0
    return report


def verify_against_torch(path, model, form: str, seed: int = 1) -> float:
    """max |pose_ORT − pose_torch| on random inputs (torch: ``model`` with its own backend)."""
    from radar_odom.onnx_model import OnnxModel

    ort_model = OnnxModel(path)
    m = copy.deepcopy(model).cpu().eval()
    inputs = example_inputs(m, form, seed=seed)
    with torch.no_grad():
        ref = StreamGraph(m)(*inputs) if form == "stream" else PairGraph(m)(*inputs)
    names = list(ort_model.info.inputs)
    out = ort_model.run({n: x.numpy() for n, x in zip(names, inputs)})
    return float(np.max(np.abs(out["pose"] - ref[0].numpy())))


SEARCHES = ("exhaustive", "fast")


def export_checkpoint(checkpoint, path, *, form: str | None = None, opset: int = DEFAULT_OPSET,
                      verify: bool = True, exporter: str = "auto", search: str = "exhaustive") -> ExportReport:
    """Export a checkpoint written by `radar-odom train` (calibrated β included).

    ``form`` defaults to ``"stream"`` (in dual mode the stream state is the previous sweep).
    ``search="fast"`` writes the stream form with the coarse-to-fine yaw search of
    `fast_search.FastStreamStep` (default settings for the profile) instead of scoring every yaw
    candidate; only the stream form has it.
    The expected sweep geometry is the checkpoint's ``train["sweep_geometry"]`` when recorded,
    else the model's (the CTS350-X / Oxford geometry the simulator also uses).
    """
    from .checkpoint import load_checkpoint

    model, meta = load_checkpoint(checkpoint, dft="fft")
    geometry = meta.get("train", {}).get("sweep_geometry")
    if geometry and model.to_cartesian is None:
        # a Cartesian model works on any sweep, but the runtime holds it to the radar it was
        # trained on; polar models build their sampling grid from it (CTS350-X by default)
        model.sweep_geometry = dict(geometry)
    training = {"checkpoint": os.path.basename(str(checkpoint)), "train": meta.get("train", {})}
    if "calibration" in meta:
        training["calibration"] = meta["calibration"]
    if search not in SEARCHES:
        raise ExportError(f"search must be one of {SEARCHES}, got {search!r}")
    if search == "fast":
        if (form or "stream") != "stream":
            raise ExportError("the fast search exists for the stream form only; use --form stream or --search exhaustive")
        from .fast_search import export_fast

        return export_fast(model, path, opset=opset, masking=meta["masking"], training_data=training, verify=verify)
    return export_model(model, path, form=form or "stream", opset=opset, masking=meta["masking"],
                        training_data=training, exporter=exporter, verify=verify)
