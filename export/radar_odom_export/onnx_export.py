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
  outputs ``pose``, ``covariance``; **sequence form** (fast search only): input ``carts``
  [T, W, W] with T left free in the file, outputs ``pose`` [T − 1, 3] and ``covariance``
  [T − 1, 3, 3], one per consecutive pair (offline batches, ``radar_odom.odometry.batch``);
* ``metadata_props``, written by `radar_odom.model_file.build_metadata` (the schema the runtime
  reads with): profile, form, sweep geometry, names and shapes, masking, training data, versions.

Rotation grids: K sampling grids of W×W×2 floats would be 126 MB at 0.2 m/px, so the exported
rotator computes them inside the graph from the K yaw values (`InGraphRotator`, the same
formula as training's precomputed grids); onnxruntime folds them once at session start.

Every search mode writes through one function, `write_graph` (`export_model`: the exhaustive
search, stream or pair form; `export_fast`: the coarse-to-fine search of `fast_search`, stream
form; `export_decoupled`: the decoupled search of `decoupled_search`, stream form;
`export_sequence`: the coarse-to-fine search on T consecutive sweeps at once, the offline batch
form). The graph-building modules (`model`, `correlation`, `dft`, `fast_search`) never import
this one: they build an ``nn.Module``, this module writes it.

Exporter: ``torch.onnx.export(dynamo=True)`` (torch.export + onnxscript) is used first — it keeps
the in-graph grid computation as a handful of nodes. ``exporter="auto"`` falls back to the
TorchScript exporter (``dynamo=False``) only when the dynamo exporter itself fails
(``torch.onnx.errors.OnnxExporterError``), and says so (a warning and a note in the report);
any other exception is a bug and propagates. TorchScript folds the grids into constants, so the
size check may then refuse large profiles. The exporter used is recorded in the metadata. The
exporters' deprecation notices are dropped; every other warning they raise (a tracer warning
that the graph may not generalise, ...) is passed on and listed in the report.

The file is written atomically: the graph goes to a temporary file in the destination folder,
every check runs on that file, and only then is it renamed over the destination. On any failure
the temporary file is removed and the destination is left as it was. The checks:

* `check_onnx_file`: opset equals the requested one (`DEFAULT_OPSET` unless asked), one file (no
  external data), at most `MAX_BYTES`, ``onnx.checker`` full check, no DFT/STFT node in the
  graph, its subgraphs or functions;
* the metadata (`radar_odom.model_file.build_metadata`, the schema the runtime reads) and the
  graph's real inputs and outputs, as the runtime loads them (`OnnxModel`);
* ``verify``: onnxruntime's pose and covariance against torch's on fresh random inputs (another
  seed than the trace's), within `Tolerance`; beyond it the export fails (`ExportError`).
"""
from __future__ import annotations

import contextlib
import copy
import json
import logging
import os
import re
import tempfile
import time
import warnings
from collections import Counter
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from torch import nn

import radar_odom
from radar_odom.errors import ExportError, RadarOdomError
from radar_odom.model_file import DEFAULT_OPSET, build_metadata, io_names

from .correlation import Rotator, make_correlation, rotate_images, rotation_grids
from .decoupled_search import DecoupledSettings, DecoupledStreamStep
from .fast_search import FastSearchSettings, FastSequenceStep, FastStreamStep

__all__ = ["DEFAULT_OPSET", "MAX_BYTES", "ExportError", "ExportReport", "Tolerance", "check_onnx_file",
           "export_checkpoint", "export_decoupled", "export_fast", "export_model", "write_graph"]

MAX_BYTES = 20 * 1024 * 1024
FORBIDDEN_OPS = frozenset({"DFT", "STFT"})
EXPORTERS = ("auto", "dynamo", "torchscript")
SEARCHES = ("exhaustive", "fast", "decoupled")
TRACE_SEED, VERIFY_SEED = 0, 1  # the example inputs traced with, and the fresh ones verified on


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
        self.exact_identity = True
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
    if m.rotator.exact_identity:  # the resampled identity's polar tables are computed in the graph already
        m.rotator = InGraphRotator(m.rotator, p.rotations_rad, p.width_px)
    m.dft = "matmul"
    return m


def sweep_shape(model) -> tuple[int, ...]:
    """Shape of one sweep input: (1, W, W), or (1, A, B') for a polar model."""
    if model.to_cartesian is not None:
        return (1, *model.to_cartesian.input_shape)
    return (1, model.profile.width_px, model.profile.width_px)


def example_inputs(model, form: str, seed: int = TRACE_SEED) -> tuple[torch.Tensor, torch.Tensor]:
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
        raise ExportError(f"{path}: initializers {external[:3]} live in external files; "
                          "the file must be self-contained")
    got = onnx_opset(proto)
    if got != opset:
        raise ExportError(f"{path}: written at opset {got}, but opset {opset} was requested "
                          f"(the exporter could not reach it); choose --opset {got} or check the exporter")
    ops = op_counts(proto)
    bad = sorted(FORBIDDEN_OPS & set(ops))
    if bad:
        raise ExportError(f"{path}: graph holds {bad} nodes, which CUDA/TensorRT and edge runtimes lack")
    try:
        onnx.checker.check_model(str(path), full_check=True)
    except onnx.checker.ValidationError as exc:
        raise ExportError(f"{path}: onnx.checker (full check) refuses the file: {exc}") from None
    return {"bytes": size, "opset": got, "ops": ops}


# ----------------------------------------------------------------------------- writing
@dataclass(frozen=True)
class Tolerance:
    """How far onnxruntime's outputs may be from torch's before an export fails.

    ``pose_m``: |Δx|, |Δy| in metres; ``yaw_rad``: |Δyaw|; ``covariance``: ‖ΔΣ‖ / ‖Σ‖ (Frobenius).
    Float32 rounding differs between the two (matmul order, fused kernels; the exhaustive
    export is compared with the FFT model it was made from). Measured on the shipped
    checkpoints (cart-0.8, cart-0.4; fast and exhaustive search): max |Δpose| ≤ 2.2e-6 and
    ‖ΔΣ‖/‖Σ‖ ≤ 1.4e-4 (cart-0.4 exhaustive), i.e. at least 45× inside these bounds, while a
    wrongly traced graph (a branch frozen at trace time, a dropped op) is off by cells.
    """

    pose_m: float = 1e-3
    yaw_rad: float = 1e-4
    covariance: float = 1e-2


DEFAULT_TOLERANCE = Tolerance()


@dataclass
class ExportReport:
    """What `write_graph` wrote and measured."""

    path: Path
    form: str
    exporter: str
    opset: int
    bytes: int
    ops: Counter
    metadata: dict
    seconds: float
    max_pose_diff: float | None = None  # max |ORT − torch| over the pose, when verified
    max_cov_diff: float | None = None  # ‖ΔΣ‖ / ‖Σ‖ of the covariance, when verified
    notes: list = field(default_factory=list)

    def summary(self) -> str:
        prof = json.loads(self.metadata["radar_odom.profile"])
        search = json.loads(self.metadata.get("radar_odom.search", "null"))
        lines = [
            f"wrote {self.path} ({self.bytes / 2**20:.2f} MiB, opset {self.opset}, {self.form} form, "
            f"{search_name(search)} search, exporter {self.exporter}, {self.seconds:.1f} s)",
            f"profile {prof['name']}: {prof['resolution_m']} m/px, {prof['width_px']} px, "
            f"inputs {json.loads(self.metadata['radar_odom.inputs'])} -> "
            f"{json.loads(self.metadata['radar_odom.outputs'])}",
            f"nodes: {sum(self.ops.values())} ({', '.join(f'{k} {v}' for k, v in self.ops.most_common(6))}, ...)",
        ]
        if self.max_pose_diff is not None:
            lines.append(f"check: onnxruntime vs torch max |Δpose| = {self.max_pose_diff:.2e}, "
                         f"covariance ‖ΔΣ‖/‖Σ‖ = {self.max_cov_diff:.2e} (fresh random inputs)")
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


def model_fields(model, form: str, masking: str | None, training_data, state_shape, search=None) -> dict:
    """The facts about ``model`` that `radar_odom.model_file.build_metadata` writes (all but the
    opset and the exporter, which `write_graph` fills in). A checkpoint from `radar-odom adapt`
    carries the radar's mount yaw in its training record: the graph carries it on."""
    adapt = (training_data or {}).get("train", {}).get("adapt", {}) if isinstance(training_data, dict) else {}
    mount = adapt.get("mount_yaw_rad") if isinstance(adapt, dict) else None
    return dict(
        profile=model.profile, form=form, sweep_geometry=model.sweep_geometry,
        input_shape=sweep_shape(model), state_shape=state_shape,
        polar_input=None if model.to_cartesian is None else
        {"num_bins": model.to_cartesian.num_bins, "bin_factor": model.to_cartesian.bin_factor},
        masking=masking or model.masking, training_data=training_data,
        version=radar_odom.__version__, torch_version=torch.__version__, search=search,
        mount_yaw_rad=float(mount) if isinstance(mount, (int, float)) and mount else None,
    )


def _metadata(fields: dict, opset: int, exporter: str) -> dict:
    try:
        return build_metadata(**fields, opset=opset, exporter=exporter)
    except RadarOdomError as exc:
        raise ExportError(f"the metadata for this model would be refused at run time: {exc}") from None


_QUIET = (DeprecationWarning, FutureWarning, PendingDeprecationWarning)  # API notices, not about the graph


def _run_exporter(kind: str, module, inputs, path, input_names, output_names, opset,
                  dynamic_axes: dict | None = None) -> list[str]:
    """One ``torch.onnx.export`` call; returns the warnings it raised that concern the graph
    (re-issued to the caller as well), dropping the exporters' deprecation notices.
    ``dynamic_axes``: ``{tensor name: {axis: symbolic name}}`` for sizes left free in the file."""
    kwargs = dict(input_names=input_names, output_names=output_names, opset_version=opset,
                  dynamo=kind == "dynamo", external_data=False)
    if dynamic_axes and kind == "dynamo":  # torch.export's form: a Dim per free input axis
        kwargs["dynamic_shapes"] = tuple(
            {axis: torch.export.Dim(f"{name}_{axis}", min=2) for axis, name in dynamic_axes.get(n, {}).items()}
            or None for n in input_names)
    elif dynamic_axes:
        kwargs["dynamic_axes"] = dynamic_axes
    if kind == "dynamo":
        kwargs["verbose"] = False
    else:
        kwargs["do_constant_folding"] = True
    # the dynamo exporter logs one line per torchvision op it cannot register: not about this graph
    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registration.level
    registration.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with torch.no_grad():
                torch.onnx.export(module, inputs, str(path), **kwargs)
    finally:
        registration.setLevel(level)
    kept = []
    for w in caught:
        if issubclass(w.category, _QUIET):
            continue
        text = f"{kind} exporter: {w.category.__name__}: {str(w.message).splitlines()[0][:300]}"
        if text not in kept:
            kept.append(text)
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return kept


def _export_with(exporter: str, module, inputs, path, input_names, output_names, opset, dynamic_axes=None):
    """Run ``exporter`` ("auto": dynamo, then TorchScript if the dynamo exporter itself fails);
    returns (the exporter used, notes)."""
    if exporter not in EXPORTERS:
        raise ExportError(f"exporter must be one of {EXPORTERS}, got {exporter!r}")
    notes = []
    for kind in (("dynamo", "torchscript") if exporter == "auto" else (exporter,)):
        try:
            return kind, notes + _run_exporter(kind, module, inputs, path, input_names, output_names, opset,
                                               dynamic_axes)
        except torch.onnx.errors.OnnxExporterError as exc:  # the exporter's own failure, nothing else
            text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc)).strip()  # the exporter colours its messages
            first = text.splitlines()[0][:300] if text else ""
            why = f"the {kind} exporter failed ({type(exc).__name__}: {first})"
            if exporter != "auto" or kind == "torchscript":
                raise ExportError(why) from exc
            warnings.warn(why + "; falling back to the TorchScript exporter", RuntimeWarning, stacklevel=3)
            notes.append(why + "; fell back to the TorchScript exporter")
    raise AssertionError("unreachable")


def verify_graph(path, reference: nn.Module, inputs, tolerance: Tolerance = DEFAULT_TOLERANCE) -> tuple[float, float]:
    """Run the file at ``path`` (as the runtime loads it: `OnnxModel`, metadata and signature
    checked) and ``reference`` in torch on ``inputs``; `ExportError` if pose or covariance differ
    beyond ``tolerance`` or are not finite. Returns (max |Δpose|, ‖ΔΣ‖/‖Σ‖)."""
    from radar_odom.onnx_model import OnnxModel

    try:
        ort_model = OnnxModel(path, threads=1)
    except RadarOdomError as exc:
        raise ExportError(f"the written file does not load as the runtime loads it: {exc}") from None
    with torch.no_grad():
        ref = reference(*inputs)
    ref_pose, ref_cov = ref[0].double().numpy(), ref[1].double().numpy()
    out = ort_model.run({n: x.numpy() for n, x in zip(ort_model.info.inputs, inputs)})
    pose, cov = out["pose"].astype(np.float64), out["covariance"].astype(np.float64)
    if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(cov))):
        raise ExportError(f"onnxruntime gives non-finite outputs (pose {pose.ravel()}) where torch gives "
                          f"{ref_pose.ravel()}: the graph does not compute the model")
    d = np.abs(pose - ref_pose)
    dpose = float(d.max())
    dcov = float(np.linalg.norm(cov - ref_cov) / max(np.linalg.norm(ref_cov), 1e-30))
    if d[..., :2].max() > tolerance.pose_m or d[..., 2].max() > tolerance.yaw_rad or dcov > tolerance.covariance:
        raise ExportError(
            f"onnxruntime and torch disagree on fresh random inputs: |Δx, Δy| = {d[..., :2].max():.3g} m "
            f"(tolerance {tolerance.pose_m:g}), |Δyaw| = {d[..., 2].max():.3g} rad (tolerance "
            f"{tolerance.yaw_rad:g}), ‖ΔΣ‖/‖Σ‖ = {dcov:.3g} (tolerance {tolerance.covariance:g}): "
            "the exported graph does not compute the model (e.g. a branch frozen at trace time); "
            "nothing was written"
        )
    return dpose, dcov


@contextlib.contextmanager
def atomic_file(path: Path):
    """A temporary file in ``path``'s folder (with the mode ``path`` keeps or a new file gets), renamed over
    ``path`` when the block ends; removed, ``path`` untouched, when the block raises."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, _file_mode(path))  # mkstemp makes it private; the result is an ordinary file
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _file_mode(path: Path) -> int:
    """The permission bits ``path`` keeps (if it exists) or an ordinary new file gets."""
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def write_graph(module: nn.Module, example_inputs, path, metadata: dict, *, input_names, output_names,
                exporter: str = "auto", opset: int = DEFAULT_OPSET, verify: bool = True, verify_inputs=None,
                reference: nn.Module | None = None, tolerance: Tolerance = DEFAULT_TOLERANCE,
                doc_string: str = "", dynamic_axes: dict | None = None) -> ExportReport:
    """Trace ``module`` on ``example_inputs`` and write it to ``path`` as a checked model file.

    ``metadata``: the fields of `radar_odom.model_file.build_metadata` but ``opset`` and
    ``exporter`` (`model_fields`), which this fills in. ``verify``: compare onnxruntime with
    ``reference`` (default: ``module``) in torch on ``verify_inputs``, which must differ from the
    trace inputs. ``dynamic_axes``: sizes left symbolic in the file (the sequence form's sweep
    count). Atomic: all checks run on a temporary file in ``path``'s folder that is then
    renamed to ``path``; on any failure ``path`` is untouched and the temporary file removed.
    Raises `ExportError` when a check fails (see the module docstring).
    """
    import onnx

    t0 = time.perf_counter()
    path = Path(path)
    form = metadata["form"]
    if verify:
        if verify_inputs is None:
            raise ValueError("verify=True needs verify_inputs (fresh inputs, not the traced ones)")
        if all(torch.equal(a, b) for a, b in zip(example_inputs, verify_inputs)):
            raise ValueError("verify_inputs are the traced inputs: verification needs fresh ones")
    _metadata(metadata, opset, exporter)  # refuse metadata the runtime would refuse before tracing
    with atomic_file(path) as tmp:
        module = module.eval()
        used, notes = _export_with(exporter, module, tuple(example_inputs), tmp, list(input_names),
                                   list(output_names), opset, dynamic_axes)
        meta = _metadata(metadata, opset, used)
        proto = onnx.load(str(tmp))
        strip_node_metadata(proto)
        del proto.metadata_props[:]
        for k, v in meta.items():
            proto.metadata_props.add(key=k, value=v)
        proto.doc_string = doc_string
        onnx.save(proto, str(tmp))
        del proto
        try:
            checked = check_onnx_file(tmp, opset)
        except ExportError as exc:  # name the file asked for, not the temporary one it never became
            raise ExportError(str(exc).replace(str(tmp), str(path))) from None
        report = ExportReport(path, form, used, checked["opset"], checked["bytes"], checked["ops"], meta,
                              0.0, notes=notes)
        if verify:
            report.max_pose_diff, report.max_cov_diff = verify_graph(
                tmp, module if reference is None else reference, tuple(verify_inputs), tolerance)
    report.seconds = time.perf_counter() - t0
    return report


# ----------------------------------------------------------------------------- search modes
def export_model(model, path, *, form: str = "stream", opset: int = DEFAULT_OPSET, masking: str | None = None,
                 training_data=None, exporter: str = "auto", verify: bool = True,
                 tolerance: Tolerance = DEFAULT_TOLERANCE) -> ExportReport:
    """Export a `MaskedCorrelator` (any DFT backend) with the exhaustive search to ``path``.

    ``exporter``: ``"auto"`` (dynamo, falling back to TorchScript if it fails), ``"dynamo"`` or
    ``"torchscript"``. ``verify`` runs the file in onnxruntime against the torch model with its
    own backend (FFT for a trained model) on fresh random inputs; see `write_graph`.
    """
    if form not in ("stream", "pair"):
        raise ValueError(f"form must be 'stream' or 'pair', got {form!r}")
    m = exportable(model)
    graph = StreamGraph if form == "stream" else PairGraph
    inputs = example_inputs(m, form, seed=TRACE_SEED)
    original = copy.deepcopy(model).cpu().eval()
    fields = model_fields(m, form, masking, training_data, tuple(inputs[1].shape) if form == "stream" else None)
    input_names, output_names = io_names(m.profile, form)
    return write_graph(
        graph(m), inputs, path, fields, input_names=input_names, output_names=output_names, exporter=exporter,
        opset=opset, verify=verify, verify_inputs=example_inputs(original, form, seed=VERIFY_SEED) if verify else None,
        reference=graph(original), tolerance=tolerance,
        doc_string=f"radar-odom {radar_odom.__version__}: Masking by Moving radar odometry, "
                   f"profile {m.profile.name}, {form} form")


class FastStreamGraph(nn.Module):
    """(sweep, prev_state) → (pose, covariance, state): `fast_search.FastStreamStep` or
    `decoupled_search.DecoupledStreamStep`."""

    def __init__(self, step: nn.Module):
        super().__init__()
        self.step = step

    def forward(self, sweep, prev_state):
        return self.step(sweep, prev_state)


def search_metadata(step) -> dict:
    """The ``radar_odom.search`` metadata of a graph searching like ``step`` (a `FastStreamStep`:
    kind ``coarse_to_fine``; a `DecoupledStreamStep`: kind ``decoupled``). The runtime and
    ``radar-odom export NAME`` read the kind back (absent metadata: the exhaustive search)."""
    if isinstance(step, DecoupledStreamStep):
        return {"kind": "decoupled", **asdict(step.settings)}
    return {"kind": "coarse_to_fine", **asdict(step.settings), "band_rotations": step.band}


def search_name(search: dict | None) -> str:
    """The ``--search`` name (`SEARCHES`) of a file's ``radar_odom.search`` metadata."""
    kind = (search or {}).get("kind")
    return {"decoupled": "decoupled", "coarse_to_fine": "fast", None: "exhaustive"}.get(kind, str(kind))


def export_fast(model, path, settings: FastSearchSettings | None = None, *, opset: int = DEFAULT_OPSET,
                masking: str | None = None, training_data=None, exporter: str = "auto", verify: bool = True,
                tolerance: Tolerance = DEFAULT_TOLERANCE) -> ExportReport:
    """Export ``model`` in the stream form with the fast search (`fast_search.FastStreamStep`);
    the file contract of `export_model` (inputs ``cart``/``polar`` + ``prev_state``; outputs
    ``pose``, ``covariance``, ``state``; metadata, checks) plus ``radar_odom.search`` metadata.
    ``verify`` compares with the torch fast step on fresh random inputs.
    """
    return _export_stream_step(model, path, FastStreamStep, settings, "fast", opset=opset, masking=masking,
                               training_data=training_data, exporter=exporter, verify=verify, tolerance=tolerance)


def export_decoupled(model, path, settings: DecoupledSettings | None = None, *, opset: int = DEFAULT_OPSET,
                     masking: str | None = None, training_data=None, exporter: str = "auto", verify: bool = True,
                     tolerance: Tolerance = DEFAULT_TOLERANCE) -> ExportReport:
    """Export ``model`` in the stream form with the decoupled search
    (`decoupled_search.DecoupledStreamStep`: yaw from the magnitude spectra, then one translation
    correlation); the file contract of `export_fast` with ``radar_odom.search`` kind
    ``decoupled``. ``verify`` compares with the torch step on fresh random inputs.
    """
    return _export_stream_step(model, path, DecoupledStreamStep, settings, "decoupled", opset=opset, masking=masking,
                               training_data=training_data, exporter=exporter, verify=verify, tolerance=tolerance)


def _export_stream_step(model, path, step_cls, settings, search_name: str, *, opset: int, masking, training_data,
                        exporter: str, verify: bool, tolerance: Tolerance) -> ExportReport:
    """The stream form of ``step_cls(model, settings)`` (a search step with ``settings.label()``
    and `search_metadata`), written by `write_graph` with the file contract of `export_model`."""
    m = copy.deepcopy(model).cpu().eval()
    step = step_cls(m, settings).eval()
    inputs = example_inputs(m, "stream", seed=TRACE_SEED)
    fields = model_fields(m, "stream", masking, training_data, tuple(inputs[1].shape), search=search_metadata(step))
    input_names, output_names = io_names(m.profile, "stream")
    return write_graph(
        FastStreamGraph(step), inputs, path, fields, input_names=input_names, output_names=output_names,
        exporter=exporter, opset=opset, verify=verify,
        verify_inputs=example_inputs(m, "stream", seed=VERIFY_SEED) if verify else None, tolerance=tolerance,
        doc_string=f"radar-odom {radar_odom.__version__}: Masking by Moving radar odometry, profile "
                   f"{m.profile.name}, stream form, {search_name} search {step.settings.label()}")


# sweeps traced and verified in the sequence form: different counts, so a graph whose sweep count
# froze at trace time fails verification instead of reaching a user
SEQUENCE_TRACE_SWEEPS = 3
SEQUENCE_VERIFY_SWEEPS = 5


def sequence_inputs(model, sweeps: int, seed: int) -> tuple[torch.Tensor]:
    """``sweeps`` plausible sweeps stacked along axis 0 (as `example_inputs` makes them)."""
    g = torch.Generator().manual_seed(seed)
    return (torch.rand((sweeps, *sweep_shape(model)[1:]), generator=g) ** 8,)


def export_sequence(model, path, settings: FastSearchSettings | None = None, *, opset: int = DEFAULT_OPSET,
                    masking: str | None = None, training_data=None, exporter: str = "auto",
                    verify: bool = True, tolerance: Tolerance = DEFAULT_TOLERANCE) -> ExportReport:
    """Export ``model`` in the sequence form (`fast_search.FastSequenceStep`, the fast search):
    input ``carts`` (``polars``) [T, W, W] with T free, outputs ``pose`` [T − 1, 3] and
    ``covariance`` [T − 1, 3, 3], one per consecutive pair; the metadata and checks of
    `export_fast` with form ``"sequence"``. Traced on `SEQUENCE_TRACE_SWEEPS` sweeps and
    verified on `SEQUENCE_VERIFY_SWEEPS`, so a sweep count frozen into the graph fails.
    The dynamo exporter keeps the sampling tables' computation in the graph (TorchScript folds
    them into constants: 22 MB at 0.4 m/px, over the size budget).
    """
    m = copy.deepcopy(model).cpu().eval()
    step = FastSequenceStep(FastStreamStep(m, settings)).eval()
    fields = model_fields(m, "sequence", masking, training_data, None, search=search_metadata(step.step))
    input_names, output_names = io_names(m.profile, "sequence")
    axes = {input_names[0]: {0: "sweeps"}, **{name: {0: "pairs"} for name in output_names}}
    return write_graph(
        step, sequence_inputs(m, SEQUENCE_TRACE_SWEEPS, TRACE_SEED), path, fields, input_names=input_names,
        output_names=output_names, exporter=exporter, opset=opset, verify=verify,
        verify_inputs=sequence_inputs(m, SEQUENCE_VERIFY_SWEEPS, VERIFY_SEED) if verify else None,
        tolerance=tolerance, dynamic_axes=axes,
        doc_string=f"radar-odom {radar_odom.__version__}: Masking by Moving radar odometry, profile "
                   f"{m.profile.name}, sequence form, fast search {step.step.settings.label()}")


def check_search_form(search: str, form: str | None) -> None:
    """`ExportError` for a search and form that do not go together (said before any work is done)."""
    if search not in SEARCHES:
        raise ExportError(f"search must be one of {SEARCHES}, got {search!r}")
    if search == "fast" and (form or "stream") == "pair":
        raise ExportError("the fast search exists for the stream and sequence forms; use --form stream or "
                          "--search exhaustive")
    if search == "decoupled" and (form or "stream") != "stream":
        raise ExportError("the decoupled search exists for the stream form; use --form stream or --search "
                          "exhaustive (pair) / fast (sequence)")
    if form == "sequence" and search != "fast":
        raise ExportError("the sequence form searches with the fast search only; add --search fast")


def export_checkpoint(checkpoint, path, *, form: str | None = None, opset: int = DEFAULT_OPSET,
                      verify: bool = True, exporter: str = "auto", search: str = "exhaustive",
                      search_settings: dict | None = None) -> ExportReport:
    """Export a checkpoint written by `radar-odom train` (calibrated β included).

    ``form`` defaults to ``"stream"`` (in dual mode the stream state is the previous sweep); the sweep form
    is `sweep_form.export_sweep_checkpoint`'s.
    ``search="fast"`` writes the stream form with the coarse-to-fine yaw search of
    `fast_search.FastStreamStep` (default settings for the profile) instead of scoring every yaw
    candidate; ``search="decoupled"`` the stream form with the decoupled search of
    `decoupled_search.DecoupledStreamStep`; ``form="sequence"`` (fast search only) writes the offline batch form
    (`export_sequence`).
    The expected sweep geometry is the checkpoint's ``train["sweep_geometry"]`` when recorded,
    else the model's (the CTS350-X / Oxford geometry the simulator also uses).
    """
    from .checkpoint import load_checkpoint

    check_search_form(search, form)
    model, meta = load_checkpoint(checkpoint, dft="fft")
    geometry = meta.get("train", {}).get("sweep_geometry")
    if geometry and model.to_cartesian is None:
        # a Cartesian model works on any sweep, but the runtime holds it to the radar it was
        # trained on; polar models build their sampling grid from it (CTS350-X by default)
        model.sweep_geometry = dict(geometry)
    training = {"checkpoint": os.path.basename(str(checkpoint)), "train": meta.get("train", {})}
    if "calibration" in meta:
        training["calibration"] = meta["calibration"]
    common = dict(opset=opset, masking=meta["masking"], training_data=training, exporter=exporter, verify=verify)
    settings = None
    if search_settings is not None and search in ("fast", "decoupled"):
        kind = FastSearchSettings if search == "fast" else DecoupledSettings
        known = {f.name for f in fields(kind)}
        unknown = sorted(set(search_settings) - known - {"kind", "band_rotations"})
        if unknown:
            raise ExportError(f"{search} search settings {unknown} are not known to this version")
        settings = kind(**{k: v for k, v in search_settings.items() if k in known})
    if form == "sequence":
        return export_sequence(model, path, settings, **common)
    if search == "fast":
        return export_fast(model, path, settings, **common)
    if search == "decoupled":
        return export_decoupled(model, path, settings, **common)
    return export_model(model, path, form=form or "stream", **common)
