"""The sweep form: a Cartesian stream graph with the polar→Cartesian drawing in front of it.

``radar-odom export NAME --form sweep`` (docs/sweep-form.md). The stream graph (``cart`` [1, W, W],
``prev_state`` → ``pose``, ``covariance``, ``state``) is kept as it is, node for node; in front of it
a small graph (`sweep_frontend`) draws the Cartesian image from the sweep as recorded, as
`radar_odom.polar.polar_to_cartesian` draws it in the SDK:

    power [A, B] float32 in [0, 1]        rows × range bins as recorded (A and B free in the file)
    azimuths_rad [A] float32              each row's angle, strictly increasing in [0, 2π)
    range_resolution_m [1] float32        metres per bin
    range_offset_m [1] float32            range of bin 0's start (bin b's centre: offset + (b + ½)·res)
    prev_state                            as the stream form

How it draws (the SDK's geometry: `radar_odom.polar`): each pixel's range and bearing are constants of
the grid (computed in float64, stored as float32); its range bin is ``u = (ρ − offset − res/2)/res``
clamped to [0, B]; its row ``v`` places the bearing on the seam-extended azimuth list (last row −
2π, the rows, first row + 2π) by piecewise-linear interpolation, as ``np.interp`` does. The
interval holding each bearing is found without a per-pixel search: a table of `TABLE_BINS` equal
bearing bins counts the azimuths in the bins before each (ScatterElements, CumSum: O(A + T) per sweep),
each pixel's table bin is a constant, and one comparison with the breakpoint inside its bin (at most one)
picks the interval. That is exact wherever no table bin holds two azimuths: spacings above 360°/2048 =
0.18° (a Navtech sweep's 400 rows are 0.9° apart). The image is then the bilinear blend of the four
neighbouring samples (``GatherElements`` on the flattened power with computed indices, rows wrapping at
the seam, bins past the last and those closer than the profile's ``near_range_m`` weighted zero), which
is what OpenCV 5's ``cv2.remap`` computes (OpenCV 4 rounds sample positions to 1/32 of a cell first).

Every op is in the default ONNX domain at the stream graph's opset: Shape, Slice, Squeeze, Reshape, Concat,
Range, ConstantOfShape, Cast, Floor, Clip, Min, arithmetic, Mod, Less, GreaterOrEqual, ScatterElements
(reduction add), CumSum and GatherElements; tested on onnxruntime (Python and Node.js), OpenVINO and
onnxruntime's OpenVINO execution provider (whole: no Reshape to an empty shape, which that provider refuses).
``Gather`` of single elements and ``GridSample`` run 20-40x slower than ``GatherElements`` and
``cv2.remap`` on onnxruntime's CPU provider (docs/latency.md), so neither is used.

What the SDK does before drawing that the graph does not: filling short runs of dropped rows
(`radar_odom.polar.fill_dropped_rows`; give dropped rows as zero or filled) and scaling 8-bit power by
1/255 (give float32 in [0, 1]).

`wrap_stream_model` makes a sweep-form model from a stream-form one (an ``onnx.ModelProto`` or a
file: the shipped ones too, no torch needed); `write_sweep_form` writes and checks it.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radar_odom.errors import ExportError
from radar_odom.model_file import SWEEP_INPUTS, SWEEP_TABLE_BINS, ModelInfo, build_metadata, io_names
from radar_odom.polar import pixel_range_bearing

# bearing-table bins over the turn: the drawing is exact while no bin holds two azimuths, i.e. for azimuth
# spacings above 360°/2048 = 0.18° (a Navtech sweep's 400 rows are 0.9° apart); the runtime's constant, which
# refuses a sweep the table cannot draw (radar_odom.sweep_arrays.sweep_form_table_problem)
TABLE_BINS = SWEEP_TABLE_BINS
_PREFIX = "sweep_form/"  # every tensor the front end adds; never a name of the stream graph


class _Builder:
    """A list of nodes and initializers with unique prefixed names."""

    def __init__(self):
        self.nodes, self.inits, self._n = [], [], 0

    def const(self, name: str, value, dtype=np.float32):
        from onnx import numpy_helper

        full = _PREFIX + name
        self.inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), full))
        return full

    def op(self, op_type: str, *inputs, **attrs) -> str:
        from onnx import helper

        self._n += 1
        out = f"{_PREFIX}{op_type.lower()}_{self._n}"
        self.nodes.append(helper.make_node(op_type, list(inputs), [out], name=out, **attrs))
        return out


def table_bin(phi_rad: np.ndarray, table_bins: int = TABLE_BINS) -> np.ndarray:
    """int64[...]: the bearing-table bin of each bearing in ``phi_rad`` (float, [0, 2π)), of ``table_bins``
    equal bins over the turn, computed in float64."""
    bins = np.floor(np.asarray(phi_rad, np.float64) * (table_bins / (2.0 * math.pi)))
    return np.clip(bins, 0, table_bins - 1).astype(np.int64)


def sweep_frontend(resolution_m: float, width_px: int, near_range_m: float, opset: int, ir_version: int,
                   output: str = "cart"):
    """The drawing graph: (``power``, ``azimuths_rad``, ``range_resolution_m``, ``range_offset_m``) →
    ``output`` float32 [1, W, W] (the module docstring), as an ``onnx.ModelProto`` at ``opset``."""
    from onnx import TensorProto, helper

    rho64, phi64 = pixel_range_bearing(resolution_m, width_px)
    g = _Builder()
    f32, i64 = TensorProto.FLOAT, TensorProto.INT64
    power, az, res, off = SWEEP_INPUTS
    c_phi = g.const("pixel_bearing_rad", phi64.astype(np.float32).ravel())
    c_rho = g.const("pixel_range_m", rho64.astype(np.float32).ravel())
    c_bin = g.const("pixel_table_bin", table_bin(phi64.ravel()), np.int64)
    two_pi = g.const("two_pi", [2.0 * math.pi])
    half, zero, one = g.const("half", [0.5]), g.const("zero", [0.0]), g.const("one", [1.0])
    i0, i1, i_1 = g.const("i0", [0], np.int64), g.const("i1", [1], np.int64), g.const("i_minus1", [-1], np.int64)
    i2, i_end = g.const("i2", [2], np.int64), g.const("i_end", [2**62], np.int64)

    def scalar(x):
        """A [1] tensor as a 0-d one (Clip's bounds, Range's limit). Squeeze, not Reshape to the empty shape:
        onnxruntime's OpenVINO provider refuses a Reshape whose shape has a zero-sized dimension, which split the
        graph there (docs/latency.md, "Runtimes and the sweep form")."""
        return g.op("Squeeze", x, i0)

    # sizes: A rows, B bins (free in the file)
    shape = g.op("Shape", power)
    rows, bins = g.op("Slice", shape, i0, i1), g.op("Slice", shape, i1, i2)
    bins_f = g.op("Cast", bins, to=f32)

    # rows: v(φ) piecewise linear through (ext[j], j), ext = [az[-1] − 2π, az, az[0] + 2π] (the seam-padded
    # rows); on interval j (ext[j] ≤ φ < ext[j + 1], j ≤ A) v = slope[j]·φ + icpt[j]
    ext = g.op("Concat", g.op("Sub", g.op("Slice", az, i_1, i_end), two_pi), az,
               g.op("Add", g.op("Slice", az, i0, i1), two_pi), axis=0)  # [A + 2]
    lo, hi = g.op("Slice", ext, i0, i_1), g.op("Slice", ext, i1, i_end)
    slope = g.op("Div", one, g.op("Sub", hi, lo))
    index = g.op("Cast", g.op("Range", g.const("r0", 0, np.int64), g.op("Squeeze", g.op("Add", rows, i1), i0),
                              g.const("r1", 1, np.int64)), to=f32)
    icpt = g.op("Sub", index, g.op("Mul", lo, slope))
    # bearing table: each table bin starts in interval `first` (the azimuths in the bins before it) and holds at
    # most the one breakpoint ext[first + 1] (the module docstring)
    per_rad = g.const("bins_per_rad", [TABLE_BINS / (2 * math.pi)])
    az_bin = g.op("Min", g.op("Cast", g.op("Floor", g.op("Mul", az, per_rad)), to=i64),
                  g.const("last_table_bin", [TABLE_BINS - 1], np.int64))
    hist = g.op("ScatterElements", g.const("table_zeros", np.zeros(TABLE_BINS)), az_bin,
                g.op("ConstantOfShape", g.op("Shape", az), value=helper.make_tensor("one", f32, [1], [1.0])), axis=0,
                reduction="add")
    first = g.op("Cast", g.op("CumSum", hist, i0, exclusive=1), to=i64)
    t_next = g.op("GatherElements", ext, g.op("Add", first, i1), axis=0)
    seg = g.op("Add", g.op("GatherElements", first, c_bin, axis=0),
               g.op("Cast", g.op("GreaterOrEqual", c_phi, g.op("GatherElements", t_next, c_bin, axis=0)), to=i64))
    v = g.op("Add", g.op("Mul", g.op("GatherElements", slope, seg, axis=0), c_phi),
             g.op("GatherElements", icpt, seg, axis=0))

    # range bins: u = (ρ − offset − res/2) / res clamped to [0, B]
    inv_res = g.op("Div", one, res)
    shift = g.op("Add", g.op("Mul", off, inv_res), half)
    u = g.op("Clip", g.op("Sub", g.op("Mul", c_rho, inv_res), shift), scalar(zero), scalar(bins_f))

    # bilinear taps: padded rows seg and seg + 1 (the interval: ⌊v⌋ but for float rounding), where padded
    # row r is row (r − 1) mod A of the power; bins ⌊u⌋ and ⌊u⌋ + 1, where a bin reads zero past the last one and,
    # as the SDK blanks them, nearer than near_range_m: b < (near − offset)/res − ½ (`readable`, b ≤ B + 1)
    c0 = g.op("Floor", u)
    fx, fy = g.op("Sub", u, c0), g.op("Sub", v, g.op("Cast", seg, to=f32))
    bin_index = g.op("Range", g.const("b0", 0.0), scalar(g.op("Add", bins_f, g.const("two", [2.0]))),
                     g.const("b1", 1.0))
    readable = g.op("Cast", g.op("Less", bin_index, bins_f), to=f32)
    if near_range_m > 0:
        nearest = g.op("Sub", g.op("Mul", g.op("Sub", g.const("near_range_m", [near_range_m]), off), inv_res), half)
        readable = g.op("Mul", readable, g.op("Cast", g.op("GreaterOrEqual", bin_index, nearest), to=f32))
    left = g.op("Cast", c0, to=i64)
    right = g.op("Add", left, i1)
    w0 = g.op("Mul", g.op("Sub", one, fx), g.op("GatherElements", readable, left, axis=0))
    w1 = g.op("Mul", fx, g.op("GatherElements", readable, right, axis=0))
    last_bin = g.op("Sub", bins, i1)
    left, right = g.op("Min", left, last_bin), g.op("Min", right, last_bin)  # in the row (their weight is 0 past it)
    padded_rows = g.op("Range", g.const("p0", 0, np.int64), g.op("Squeeze", g.op("Add", rows, i2), i0),
                       g.const("p1", 1, np.int64))
    row_start = g.op("Mul", g.op("Mod", g.op("Add", padded_rows, g.op("Sub", rows, i1)), rows), bins)  # [A + 2]
    flat = g.op("Reshape", power, i_1)

    def blend(row):
        start = g.op("GatherElements", row_start, row, axis=0)
        at_left = g.op("GatherElements", flat, g.op("Add", start, left), axis=0)
        at_right = g.op("GatherElements", flat, g.op("Add", start, right), axis=0)
        return g.op("Add", g.op("Mul", at_left, w0), g.op("Mul", at_right, w1))

    top, bottom = blend(seg), blend(g.op("Add", seg, i1))
    image = g.op("Add", top, g.op("Mul", fy, g.op("Sub", bottom, top)))
    g.nodes.append(helper.make_node("Reshape", [image, g.const("image_shape", [1, width_px, width_px], np.int64)],
                                    [output], name=_PREFIX + "image"))
    inputs = [
        helper.make_tensor_value_info(power, f32, ["azimuths", "bins"]),
        helper.make_tensor_value_info(az, f32, ["azimuths"]),
        helper.make_tensor_value_info(res, f32, [1]),
        helper.make_tensor_value_info(off, f32, [1]),
    ]
    graph = helper.make_graph(g.nodes, "sweep_frontend", inputs,
                              [helper.make_tensor_value_info(output, f32, [1, width_px, width_px])],
                              initializer=g.inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)], ir_version=ir_version)


def _default_opset(proto) -> int:
    for o in proto.opset_import:
        if o.domain in ("", "ai.onnx"):
            return int(o.version)
    raise ExportError("the stream graph declares no default-domain opset")


def _load_onnx(path):
    """``onnx.load`` of a model path, its failures typed (protobuf's DecodeError for garbage, ...)."""
    import os

    import onnx

    from radar_odom.errors import InputTypeError, InvalidModelError, ModelNotFoundError

    if not isinstance(path, (str, os.PathLike)):
        raise InputTypeError(f"the stream-form model must be an onnx.ModelProto or a path to an .onnx file, got "
                             f"{type(path).__name__}")
    if not Path(path).is_file():
        raise ModelNotFoundError(f"{path}: no such model file")
    try:
        return onnx.load(str(path))
    except Exception as exc:  # noqa: BLE001 - protobuf's DecodeError, onnx's own, OSError: one typed error
        lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
        detail = (lines[0] if lines else type(exc).__name__)[:200]
        raise InvalidModelError(f"{path}: not a readable ONNX model ({detail}); give the stream-form .onnx that "
                                "radar-odom export wrote") from None


def wrap_stream_model(stream):
    """A sweep-form ``onnx.ModelProto`` from a Cartesian stream-form model (a ModelProto or a path): the
    drawing graph (`sweep_frontend`) feeding its ``cart`` input, its metadata carried over with form
    ``sweep``. `ExportError` for a model that is not a Cartesian stream-form radar-odom model,
    `InvalidModelError` for a file that is no ONNX model (truncated, garbage), `ModelNotFoundError` for a
    path that is not there, `InputTypeError` for anything but a ModelProto or a path."""
    import onnx
    from onnx import compose

    proto = stream if isinstance(stream, onnx.ModelProto) else _load_onnx(stream)
    meta = {p.key: p.value for p in proto.metadata_props}
    info = ModelInfo.from_metadata(meta, source="stream graph")
    if info.form != "stream" or info.profile.input_kind != "cartesian":
        raise ExportError(f"the sweep form wraps a Cartesian stream-form graph; this one is {info.form} form with "
                          f"{info.profile.input_kind} input")
    p = info.profile
    front = sweep_frontend(p.resolution_m, p.width_px, p.near_range_m, _default_opset(proto), proto.ir_version,
                           output=info.inputs[0])
    # the front end uses the default domain only; the stream graph's other domains (local functions) come along
    front.opset_import.extend(o for o in proto.opset_import if o.domain not in ("", "ai.onnx"))
    inner = onnx.ModelProto()
    inner.CopyFrom(proto)
    del inner.metadata_props[:]
    merged = compose.merge_models(front, inner, io_map=[(info.inputs[0], info.inputs[0])],
                                  doc_string=proto.doc_string.replace("stream form", "sweep form"))
    merged.producer_name, merged.producer_version = proto.producer_name, proto.producer_version
    fields = dict(
        profile=info.profile, form="sweep", sweep_geometry=info.sweep_geometry,
        input_shape=(info.sweep_geometry["num_azimuths"], info.sweep_geometry["num_bins"]),
        state_shape=info.state_shape, masking=info.masking, training_data=info.training_data, version=info.version,
        opset=info.opset or _default_opset(proto), exporter=info.exporter, torch_version=info.torch_version,
        search=info.search, quantization=info.quantization, mount_yaw_rad=info.mount_yaw_rad or None)
    for k, v in build_metadata(**fields, source="sweep form").items():
        merged.metadata_props.add(key=k, value=v)
    names = [i.name for i in merged.graph.input]
    if names != io_names(info.profile, "sweep")[0]:
        raise ExportError(f"the merged graph's inputs are {names}, expected {io_names(info.profile, 'sweep')[0]}")
    return merged


# how far the sweep form's poses may be from the SDK path's (stream graph on `polar_to_cartesian`'s image)
PARITY_POSE_M, PARITY_YAW_RAD = 1e-3, 1e-4
VERIFY_SWEEPS = 3  # simulated sweeps (seed `VERIFY_SEED`) an export is checked on: two matches after the first
VERIFY_SEED = 1


@dataclass
class SweepFormReport:
    """What `write_sweep_form` wrote: the file, its metadata and, when verified, the largest pose difference
    from the SDK path (m for x/y, rad for yaw) over `VERIFY_SWEEPS` simulated sweeps."""

    path: Path
    metadata: dict
    max_dxy_m: float | None = None
    max_dyaw_rad: float | None = None

    def summary(self) -> str:
        text = f"sweep form: wrote {self.path} (inputs {json.loads(self.metadata['radar_odom.inputs'])})"
        if self.max_dxy_m is not None:
            text += (f"; check: against the stream graph on the SDK's Cartesian image, max |Δx, Δy| = "
                     f"{self.max_dxy_m:.2e} m, |Δyaw| = {self.max_dyaw_rad:.2e} rad ({VERIFY_SWEEPS} simulated sweeps)")
        return text


def parity(sweep_model, stream_model, scans) -> tuple[float, float]:
    """(max |Δx, Δy| m, max |Δyaw| rad) between the graph poses of a sweep-form model and of a stream-form one
    fed the SDK's Cartesian images (`OnnxModel`s), each chaining its own state over ``scans`` (RadarScans)."""
    from radar_odom.odometry.graph_step import GraphStep
    from radar_odom.odometry.sweep_input import graph_input

    steps = [GraphStep(m) for m in (sweep_model, stream_model)]
    refs = [step.first(graph_input(scans[0], step.info)) for step in steps]
    dxy = dyaw = 0.0
    for scan in scans[1:]:
        out = [step.match(graph_input(scan, step.info), ref) for step, ref in zip(steps, refs)]
        if any(o is None for o in out):
            raise ExportError("the sweep form or its stream graph gives a non-finite pose on a simulated sweep")
        d = np.abs(out[0][0] - out[1][0])
        dxy, dyaw = max(dxy, float(d[:2].max())), max(dyaw, float(d[2]))
        refs = [o[2] for o in out]
    return dxy, dyaw


def write_sweep_form(stream, path, verify: bool = True) -> SweepFormReport:
    """Write the sweep form of ``stream`` (a path; `wrap_stream_model`) to ``path``, checked as every export is
    (`onnx_export.check_onnx_file`), loaded as the runtime loads it and, with ``verify``, its poses held to the
    stream graph's on the SDK's images over `VERIFY_SWEEPS` simulated sweeps (`parity`; `ExportError` beyond
    `PARITY_POSE_M` / `PARITY_YAW_RAD`). Atomic: a temporary file renamed over ``path`` once every check passed."""
    import onnx

    from radar_odom.onnx_model import OnnxModel

    from .onnx_export import atomic_file, check_onnx_file, onnx_opset

    proto = wrap_stream_model(stream)
    with atomic_file(Path(path)) as tmp:
        onnx.save(proto, str(tmp))
        check_onnx_file(tmp, onnx_opset(proto))
        model = OnnxModel(tmp, threads=1)  # metadata and signature, as the runtime holds them
        report = SweepFormReport(Path(path), dict(model.session.get_modelmeta().custom_metadata_map))
        if verify:
            from radar_odom.sim import simulate_drive

            scans = [f.scan for f in simulate_drive(seed=VERIFY_SEED, frames=VERIFY_SWEEPS)]
            report.max_dxy_m, report.max_dyaw_rad = parity(model, OnnxModel(stream, threads=1), scans)
            if report.max_dxy_m > PARITY_POSE_M or report.max_dyaw_rad > PARITY_YAW_RAD:
                raise ExportError(
                    f"the sweep form's poses differ from the stream graph's on the SDK's images by "
                    f"{report.max_dxy_m:.3g} m / {report.max_dyaw_rad:.3g} rad (tolerance {PARITY_POSE_M:g} m / "
                    f"{PARITY_YAW_RAD:g} rad): the in-graph drawing is not the SDK's; nothing was written")
    return report


def export_sweep_checkpoint(checkpoint, path, *, opset: int, verify: bool = True, exporter: str = "auto",
                            search: str = "exhaustive", search_settings: dict | None = None, form: str = "sweep"):
    """`onnx_export.export_checkpoint`'s stream form of ``checkpoint`` (``search`` and its settings), then its
    sweep form at ``path`` (`write_sweep_form`); returns the stream export's `ExportReport`, made to describe
    the file written, with the sweep form's check in its notes."""
    import tempfile

    from .onnx_export import check_onnx_file, export_checkpoint

    if form != "sweep":
        raise ExportError(f"export_sweep_checkpoint writes the sweep form, not {form!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".sweep-form-", dir=path.parent) as tmp:
        report = export_checkpoint(checkpoint, Path(tmp) / "stream.onnx", form="stream", opset=opset, verify=verify,
                                   exporter=exporter, search=search, search_settings=search_settings)
        sweep = write_sweep_form(report.path, path, verify=verify)
    checked = check_onnx_file(path, opset)
    report.notes.append(sweep.summary())
    report.path, report.form, report.bytes, report.ops = path, "sweep", checked["bytes"], checked["ops"]
    report.metadata = sweep.metadata
    return report
