"""An int8 masker: static QDQ quantisation of an exported model's U-Net ``Conv`` nodes.

    radar-odom export cart-0.8 --search fast --quantize static -o cart-0.8-int8.onnx

The scheme's name is ``static`` (`QUANTIZE_CHOICES`; ``int8``, its earlier name, is accepted as a
synonym and recorded as ``static``).

`quantize_model` takes a written (fp32, checked) radar-odom ONNX file and writes a copy in which
every ``Conv`` node — in these graphs only the masker's U-Net has any — reads
QuantizeLinear→DequantizeLinear activations and int8 weights (per output channel by default);
onnxruntime's CPU provider fuses each DQ→Conv→Q group into an integer convolution. Nothing else
is quantised: the input normalisation, the rotation, the matmul DFT, the correlation and the
soft-argmax stay float32 (`onnxruntime.quantization.quantize_static` with
``op_types_to_quantize=["Conv"]``).

Calibration: activation ranges (percentile by default) come from simulated sweeps, fed to the graph
as the runtime feeds them — each sweep on the profile's Cartesian grid (`radar_odom.polar.
polar_to_cartesian`, what `RadarOdometer` does to a scan) with the stream state the fp32 graph
made from the sweep before it. The default calibration drives are validation seeds
(`CALIBRATION_SEEDS`, 2000–2001: never the evaluation seeds ≥ 5000 the accuracy is measured on).
Real sweeps may be added (`real_calibration_drives`): the shared RADIATE city drive's sweeps *except*
its held-out last 80 (`REAL_HOLDOUT`, the stretch the scorecard's "real drive held-out" row reads:
never calibrated or tuned on), read as `radar-odom calibrate` reads them (`data.scan_to_cartesian`);
the metadata then names the recording, the sweeps given and the held-out count. As with the
simulated drives, the first half of each drive given calibrates and its second half is the check's
(unless other check drives are given): ``"sweeps": [0, 200]`` of the shared drive means 0–99
calibrated, 100–199 checked, 200–279 never read.

The file keeps the fp32 file's metadata plus ``radar_odom.quantization`` (JSON: scheme, quantised
op types and node count, weight/activation types, per-channel, calibration method and drives,
onnxruntime version). It is written atomically, like `onnx_export.write_graph`: a temporary file
in the destination folder is checked (`onnx_export.check_onnx_file`: opset, one file, size,
``onnx.checker``, no DFT node; QDQ pairs around ``Conv`` only; the metadata and signature as the
runtime loads them), then verified against the fp32 file on held-back simulated sweeps
(`INT8_TOLERANCE`: a quantised masker cannot match torch to float rounding), and only then
renamed over the destination.

Measured (shipped cart-0.8 / cart-0.4 of commit f6c4422, held-out drives: seeds 5000–5001 × 4
scenarios × 240 sweeps, KITTI t %, 1 thread, fp32 and int8 graphs interleaved in one process):
this recipe (percentile, first/last Conv float32) costs +0.45 / +0.41 t% points (19.43 → 19.89,
11.96 → 12.37) for a graph 0.84–0.86× / 0.91–0.94× as slow; every Conv int8 with MinMax ranges
costs +1.9 points at 0.8 m. Not within the 0.1-point bar for shipping; an export option only.

Re-measured 2026-12-07 (issue 52, `benchmarks/frontier.py`; the shipped cart-0.4 of bada841, this recipe
calibrated on the simulated validation drives and the shared RADIATE drive's sweeps 0–199): the graph 0.94–0.97×
today's (interleaved in one process, 2 threads and 1 thread, on a loaded 2-core machine); every Conv int8
0.97–0.99×, slower than keeping the first and last float. On the release scorecard against the float file: no row
worse on one run of fresh seeds (generator 1731379452), one row worse on another (810046465: the 0.2 °/sweep
bend's yaw reading; calibrated on simulated drives only, the same row on the same seeds). Not shipped
(docs/scorecard.md, "Static int8 cart-0.4 candidates judged and not shipped").

It works on any exported file (no checkpoint, no tracing); its file checks are `onnx_export`'s,
so it needs torch and onnx like the rest of this package (radar-odom-export).
"""
from __future__ import annotations

import contextlib
import io
import logging
import os
import tempfile
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radar_odom.errors import ExportError, RadarOdomError
from radar_odom.model_file import ModelInfo, build_metadata

__all__ = ["CALIBRATION_SCENARIOS", "CALIBRATION_SEEDS", "DEFAULT_FLOAT_CONVS", "INT8_TOLERANCE", "QUANTIZE_CHOICES",
           "QuantizeReport", "REAL_HOLDOUT", "SCHEME", "SweepFeeds", "calibration_drives", "check_qdq_conv_only",
           "export_quantized", "quantize_model", "quantize_scheme", "real_calibration_drives", "stream_feeds"]

SCHEME = "static"  # static QDQ: activation ranges fixed by calibration, written in the metadata's "scheme"
QUANTIZE_CHOICES = (SCHEME, "int8")  # "int8": the scheme's earlier name, accepted as a synonym
REAL_HOLDOUT = 80  # the shared drive's last sweeps, never calibrated on (real_pairs.DEFAULT_HOLDOUT, the scorecard's)
CALIBRATION_SEEDS = (2000, 2001)  # validation seeds (radar_odom_export.data policy), not evaluation
CALIBRATION_SCENARIOS = ("urban", "heavy_traffic", "open", "highway")
DEFAULT_FLOAT_CONVS = "first,last"  # cart-0.8, held-out drives: +1.9 t% points all int8 (MinMax), +0.6 without them
QDQ_OPS = frozenset({"QuantizeLinear", "DequantizeLinear"})


@dataclass(frozen=True)
class Int8Tolerance:
    """How far the quantised file's pose may be from the fp32 file's on the same sweeps.

    Bounds on the median and the 95th percentile over sweeps, not the worst sweep: int8 masks
    move a soft-argmax by a few hundredths of a cell on typical sweeps, but where the fp32
    correlation itself is ambiguous (two near-equal peaks) a small change of the mask can flip
    the peak by cells (cart-0.8, 472 validation sweeps: median 0.036 cells, worst 10 cells). A
    broken quantisation (a wrong scale, a clipped activation range) moves most sweeps by cells.
    """

    median_cells: float = 0.25  # median over sweeps of max(|Δx|, |Δy|), grid cells
    p95_cells: float = 1.0  # its 95th percentile
    median_yaw_rad: float = 2e-3
    p95_yaw_rad: float = 1e-2


INT8_TOLERANCE = Int8Tolerance()


@dataclass
class QuantizeReport:
    """What `quantize_model` wrote and measured."""

    path: Path
    bytes: int
    quantization: dict
    conv_nodes: int
    qdq_nodes: int
    verify_sweeps: int = 0
    median_pose_cells: float | None = None  # median over sweeps of max(|Δx|, |Δy|) vs fp32, in cells
    p95_pose_cells: float | None = None
    max_pose_cells: float | None = None
    p95_yaw_rad: float | None = None
    max_yaw_rad: float | None = None
    seconds: float = 0.0
    notes: list = field(default_factory=list)

    def summary(self) -> str:
        q = self.quantization
        lines = [f"quantised {self.conv_nodes} Conv nodes ({q['scheme']}, weights {q['weight_type']}"
                 f"{' per channel' if q['per_channel'] else ''}, activations {q['activation_type']}, "
                 f"{q['calibration']['method']} calibration on {q['calibration']['sweeps']} sweeps"
                 f"{_real_note(q['calibration'])}) "
                 f"-> {self.path} ({self.bytes / 2**20:.2f} MiB, {self.qdq_nodes} Q/DQ nodes, {self.seconds:.1f} s)"]
        if self.median_pose_cells is not None:
            lines.append(f"check: int8 vs fp32 graph on {self.verify_sweeps} held-back sweeps: |Δx, Δy| median "
                         f"{self.median_pose_cells:.3f} cells, p95 {self.p95_pose_cells:.3f}, "
                         f"max {self.max_pose_cells:.3f}; "
                         f"|Δyaw| p95 {self.p95_yaw_rad:.2e} rad, max {self.max_yaw_rad:.2e} rad")
        return "\n".join(lines + self.notes)


def _real_note(calibration: dict) -> str:
    real = calibration.get("real") or []
    return "".join(f", real: {r['recording']} sweeps {r['sweeps'][0]}–{r['sweeps'][1] - 1} of {r['of']} "
                   f"(last {r['held_out']} held out)" for r in real)


# ----------------------------------------------------------------------------- sweeps
def calibration_drives(info: ModelInfo, seeds: Sequence[int] = CALIBRATION_SEEDS,
                       scenarios: Sequence[str] = CALIBRATION_SCENARIOS, frames: int = 120,
                       workers: int = 1) -> list[np.ndarray]:
    """Simulated drives as float32[F, W, W] Cartesian sweeps on ``info``'s grid, as the runtime
    makes them from scans; through the exporter's drive cache (`data.build_drives`)."""
    if info.profile.input_kind != "cartesian":
        raise ExportError("int8 quantisation is implemented for Cartesian-input models only")
    from .data import build_drives, sim_specs

    specs = sim_specs(seeds, scenarios, frames)
    drives = build_drives(info.profile, specs, workers, with_labels=False, desc="calibration drives")
    return [np.asarray(d.images, dtype=np.float32) for d in drives]


def quantize_scheme(name: str) -> str:
    """The scheme a ``--quantize`` word names (``static``; ``int8`` is its synonym); `ExportError` otherwise."""
    if name not in QUANTIZE_CHOICES:
        raise ExportError(f"quantize must be one of {QUANTIZE_CHOICES} (int8 is a synonym of static), got {name!r}")
    return SCHEME


def real_calibration_drives(info: ModelInfo, paths: Sequence, holdout: int = REAL_HOLDOUT,
                            max_sweeps: int | None = None) -> tuple[list[np.ndarray], dict]:
    """Real recordings as float32[F, W, W] Cartesian sweeps on ``info``'s grid, each without its last
    ``holdout`` sweeps (never calibrated on), at most ``max_sweeps`` consecutive sweeps from its start;
    and their provenance for the metadata: ``{"real": [{"recording", "sweeps": [first, end), "of",
    "held_out"}]}``. `ExportError` where a recording has fewer than two sweeps outside the held-out stretch."""
    if info.profile.input_kind != "cartesian":
        raise ExportError("int8 quantisation is implemented for Cartesian-input models only")
    from radar_odom.errors import StampWarning
    from radar_odom.io import read_sequence

    from .data import scan_to_cartesian

    drives, used = [], []
    for path in paths:
        with warnings.catch_warnings():  # the sweeps' stamps are not used here: their repair is no news
            warnings.simplefilter("ignore", StampWarning)
            seq = read_sequence(path)
        end = len(seq) - int(holdout)
        if max_sweeps is not None:
            end = min(end, int(max_sweeps))
        if end < 2:
            raise ExportError(f"{path}: {len(seq)} sweeps, {holdout} held out: fewer than two to calibrate on")
        drives.append(np.stack([scan_to_cartesian(seq.scan(i), info.profile) for i in range(end)]).astype(np.float32))
        used.append({"recording": Path(path).name, "sweeps": [0, end], "of": len(seq), "held_out": int(holdout)})
    return drives, {"real": used}


def stream_feeds(session, info: ModelInfo, drives: Sequence[np.ndarray], every: int = 1) -> list[dict]:
    """Stream-form feeds ``{sweep input: x_k, prev_state: state_{k-1}}``: each drive run through
    ``session`` (an fp32 graph) from an all-zero state, as `RadarOdometer` runs a stream; every
    ``every``-th step is kept (the first sweep's, against the zero state, never)."""
    if info.form != "stream":
        raise ExportError("int8 quantisation is implemented for stream-form models only")
    sweep_name, state_name = info.inputs
    feeds = []
    for images in drives:
        state = np.zeros(info.state_shape, dtype=np.float32)
        for k, img in enumerate(images):
            x = np.ascontiguousarray(img, dtype=np.float32)[None]
            if k > 0 and (k - 1) % every == 0:
                feeds.append({sweep_name: x, state_name: state})
            state = session.run(["state"], {sweep_name: x, state_name: state})[0]
    return feeds


try:  # a CalibrationDataReader when onnxruntime.quantization imports (it needs the onnx package)
    from onnxruntime.quantization import CalibrationDataReader as _Reader
except ImportError:  # pragma: no cover - the export extra is missing; quantize_model says so
    _Reader = object


class SweepFeeds(_Reader):
    """`onnxruntime.quantization.CalibrationDataReader` over a list of feeds (`stream_feeds`)."""

    def __init__(self, feeds: Sequence[dict]):
        self.feeds = list(feeds)
        self._it = iter(self.feeds)

    def get_next(self):
        return next(self._it, None)

    def rewind(self):
        self._it = iter(self.feeds)

    def __len__(self):
        return len(self.feeds)


# ----------------------------------------------------------------------------- checks
def check_qdq_conv_only(proto, float_convs=()) -> tuple[int, int]:
    """Every QuantizeLinear/DequantizeLinear sits next to a ``Conv`` (Q→DQ into a Conv's input,
    DQ of its weights into it, or Q→DQ of its output) and every ``Conv`` reads dequantised input
    and weights;
    `ExportError` otherwise. Returns (Conv nodes, Q/DQ nodes)."""
    nodes = list(proto.graph.node)
    producer = {o: n for n in nodes for o in n.output}
    consumers: dict[str, list] = {}
    for n in nodes:
        for i in n.input:
            consumers.setdefault(i, []).append(n)
    convs = [n for n in nodes if n.op_type == "Conv" and n.name not in set(float_convs)]
    qdq = [n for n in nodes if n.op_type in QDQ_OPS]
    for c in convs:
        for i in c.input[:2]:
            p = producer.get(i)
            if p is None or p.op_type != "DequantizeLinear":
                raise ExportError(f"Conv {c.name!r} input {i!r} is not dequantised: the masker is not fully quantised")

    def feeds_conv(n) -> bool:  # a DQ whose every consumer is a Conv
        nxt = consumers.get(n.output[0], [])
        return bool(nxt) and all(c.op_type == "Conv" for c in nxt)

    def after_conv(n) -> bool:  # a Q reading a Conv's output
        src = producer.get(n.input[0])
        return src is not None and src.op_type == "Conv"

    def touches_conv(n) -> bool:
        if n.op_type == "QuantizeLinear":  # quantises a Conv's output, or an input only Convs read
            nxt = consumers.get(n.output[0], [])
            return after_conv(n) or (bool(nxt) and all(d.op_type == "DequantizeLinear" and feeds_conv(d)
                                                       for d in nxt))
        src = producer.get(n.input[0])  # DequantizeLinear: into a Conv, or out of a Conv's Q
        return feeds_conv(n) or (src is not None and src.op_type == "QuantizeLinear" and after_conv(src))

    stray = [n.name or n.op_type for n in qdq if not touches_conv(n)]
    if stray:
        raise ExportError(f"Q/DQ nodes {stray[:4]} are not next to a Conv: something besides the masker was quantised")
    return len(convs), len(qdq)


def _pose_diffs(fp32, int8, info: ModelInfo, feeds: Sequence[dict]) -> np.ndarray:
    """[N, 3] |Δx|/res, |Δy|/res, |Δyaw| between the two sessions on ``feeds``."""
    res = info.profile.resolution_m
    out = []
    for f in feeds:
        a = fp32.run(["pose"], f)[0].reshape(3).astype(np.float64)
        b = int8.run(["pose"], f)[0].reshape(3).astype(np.float64)
        d = np.abs(a - b)
        out.append([d[0] / res, d[1] / res, d[2]])
    return np.asarray(out, dtype=np.float64)


# ----------------------------------------------------------------------------- writing
def _session(path, threads: int = 1):
    from radar_odom.onnx_model import OnnxModel

    return OnnxModel(path, threads=threads)


def quantize_model(src, path, *, drives: Sequence[np.ndarray] | None = None, verify_drives=None,
                   per_channel: bool = True, activation_type: str = "uint8", method: str = "percentile",
                   calibration_every: int = 2, calibration: dict | None = None, verify: bool = True,
                   tolerance: Int8Tolerance = INT8_TOLERANCE, threads: int = 1,
                   exclude: str = DEFAULT_FLOAT_CONVS, extra_options: dict | None = None,
                   real: Sequence = (), real_holdout: int = REAL_HOLDOUT,
                   real_max_sweeps: int | None = None) -> QuantizeReport:
    """Write an int8-masker copy of the radar-odom file ``src`` to ``path`` (see the module doc).

    ``drives``: calibration sweeps, a list of float32[F, W, W] (default: `calibration_drives`);
    ``verify_drives``: other sweeps to compare with the fp32 file on (default: the second half of
    every calibration drive is held back from calibration for it). ``activation_type``:
    ``"uint8"`` (onnxruntime's fast U8S8 path on x86) or ``"int8"``. ``method``: ``"minmax"``,
    ``"percentile"`` (default; onnxruntime's 99.999th) or ``"entropy"``. ``exclude``: ``"first"``,
    ``"last"``, ``"first,last"`` (default) or ``""``: those of the masker's Conv nodes (in graph
    order) stay float32 — the first reads the heavy-tailed normalised sweep, the last writes the
    mask logits. ``calibration``: provenance
    recorded in the metadata. ``extra_options``: passed to ``quantize_static`` (and recorded).
    ``real``: real recordings (e.g. the shared RADIATE drive) whose sweeps, all but the last
    ``real_holdout`` (at most ``real_max_sweeps`` from the start), are added to ``drives`` —
    half of each for calibration, half for the check, like the simulated ones — and named in the
    metadata's ``calibration.real``.
    `ExportError` if a check fails; ``path`` is then untouched.
    """
    import onnx
    import onnxruntime
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static

    from .onnx_export import _file_mode, check_onnx_file, onnx_opset

    t0 = time.perf_counter()
    src, path = Path(src), Path(path)
    base = _session(src, threads)
    info = base.info
    if info.profile.input_kind != "cartesian" or info.form != "stream":
        raise ExportError("int8 quantisation is implemented for Cartesian stream-form models only")
    if info.quantization is not None:
        raise ExportError(f"{src}: already quantised")
    methods = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
               "entropy": CalibrationMethod.Entropy}
    types = {"uint8": QuantType.QUInt8, "int8": QuantType.QInt8}
    if method not in methods or activation_type not in types:
        raise ExportError(f"method must be one of {sorted(methods)}, activation_type one of {sorted(types)}")
    if drives is None:
        drives = calibration_drives(info)
        calibration = {**(calibration or {}), "seeds": list(CALIBRATION_SEEDS),
                       "scenarios": list(CALIBRATION_SCENARIOS), "frames": 120}
    drives = [np.asarray(d, dtype=np.float32) for d in drives]
    if real:
        real_drives, provenance = real_calibration_drives(info, real, real_holdout, real_max_sweeps)
        drives = drives + real_drives
        calibration = {**(calibration or {}), **provenance}
    if verify_drives is None:  # hold back the second half of each drive
        verify_drives = [d[len(d) // 2:] for d in drives]
        drives = [d[: len(d) // 2] for d in drives]
    feeds = stream_feeds(base.session, info, drives, every=calibration_every)
    if not feeds:
        raise ExportError("no calibration sweeps (give drives of at least two sweeps)")
    src_proto = onnx.load(str(src), load_external_data=False)
    opset = onnx_opset(src_proto)
    conv_names = [n.name for n in src_proto.graph.node if n.op_type == "Conv"]
    del src_proto
    which = {w for w in exclude.replace(" ", "").split(",") if w}
    if which - {"first", "last"}:
        raise ExportError(f"exclude must name 'first' and/or 'last', got {exclude!r}")
    excluded = sorted({conv_names[0 if w == "first" else -1] for w in which} if conv_names else ())

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, _file_mode(path))
    try:
        root = logging.getLogger()  # the quantiser's advice to pre-process (shape inference) is noise here
        level = root.level
        root.setLevel(logging.ERROR)
        try:  # its histogram calibrators also print their progress: not for the user
            with contextlib.redirect_stdout(io.StringIO()):
                quantize_static(str(src), str(tmp), SweepFeeds(feeds), quant_format=QuantFormat.QDQ,
                                op_types_to_quantize=["Conv"], per_channel=per_channel, reduce_range=False,
                                activation_type=types[activation_type], weight_type=QuantType.QInt8,
                                calibrate_method=methods[method], nodes_to_exclude=excluded or None,
                                extra_options=dict(extra_options or {}))
        finally:
            root.setLevel(level)
        proto = onnx.load(str(tmp))
        convs, qdqs = check_qdq_conv_only(proto, float_convs=excluded)
        quantization = {
            "scheme": SCHEME, "format": "qdq", "op_types": ["Conv"], "nodes": convs,
            "float_nodes": [w for w in ("first", "last") if w in which], "weight_type": "int8",
            "activation_type": activation_type, "per_channel": bool(per_channel),
            "calibration": {"method": method, "sweeps": len(feeds), "every": calibration_every,
                            **(calibration or {})},
            "onnxruntime": onnxruntime.__version__,
            **({"extra_options": dict(extra_options)} if extra_options else {}),
        }
        # the float32 file's metadata, re-written with the quantisation (the writer refuses what the runtime would)
        try:
            meta = build_metadata(
                profile=info.profile, form=info.form, sweep_geometry=info.sweep_geometry,
                input_shape=info.input_shape, state_shape=info.state_shape, polar_input=info.polar_input,
                masking=info.masking, training_data=info.training_data, version=info.version,
                opset=info.opset if info.opset is not None else opset, exporter=info.exporter,
                torch_version=info.torch_version, search=info.search, quantization=quantization, source=str(path))
        except (RadarOdomError, ValueError) as exc:
            raise ExportError(f"the quantised file's metadata would be refused at run time: {exc}") from None
        del proto.metadata_props[:]
        for k, v in meta.items():
            proto.metadata_props.add(key=k, value=v)
        proto.doc_string = (proto.doc_string or "") + f" (masker Conv int8 QDQ, {method} calibration)"
        onnx.save(proto, str(tmp))
        del proto
        checked = check_onnx_file(tmp, opset)
        report = QuantizeReport(path, checked["bytes"], quantization, convs, qdqs)
        if verify:
            q = _session(tmp, threads)  # loads as the runtime loads it: metadata and signature checked
            vfeeds = stream_feeds(base.session, info, verify_drives)
            d = _pose_diffs(base.session, q.session, info, vfeeds)
            if not np.all(np.isfinite(d)):
                raise ExportError("the quantised graph gives non-finite poses where the fp32 graph does not")
            cells = d[:, :2].max(axis=1)
            report.verify_sweeps = len(d)
            report.median_pose_cells = float(np.median(cells))
            report.max_pose_cells = float(cells.max())
            report.p95_pose_cells = float(np.percentile(cells, 95))
            report.max_yaw_rad = float(d[:, 2].max())
            report.p95_yaw_rad = float(np.percentile(d[:, 2], 95))
            med_yaw = float(np.median(d[:, 2]))
            if (report.median_pose_cells > tolerance.median_cells or report.p95_pose_cells > tolerance.p95_cells
                    or med_yaw > tolerance.median_yaw_rad or report.p95_yaw_rad > tolerance.p95_yaw_rad):
                raise ExportError(
                    f"the int8 graph strays from the fp32 graph on {len(d)} held-back sweeps: |Δx, Δy| median "
                    f"{report.median_pose_cells:.3g} cells (tolerance {tolerance.median_cells:g}), p95 "
                    f"{report.p95_pose_cells:.3g} (tolerance {tolerance.p95_cells:g}); |Δyaw| median {med_yaw:.3g} "
                    f"rad (tolerance {tolerance.median_yaw_rad:g}), p95 {report.p95_yaw_rad:.3g} (tolerance "
                    f"{tolerance.p95_yaw_rad:g}); nothing was written")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    report.seconds = time.perf_counter() - t0
    return report


def export_quantized(checkpoint, path, *, quantize: str = SCHEME, exclude: str = DEFAULT_FLOAT_CONVS,
                     verify: bool = True, drives: Sequence[np.ndarray] | None = None,
                     calibration: dict | None = None, real: Sequence = (), real_holdout: int = REAL_HOLDOUT,
                     **export_kwargs):
    """`onnx_export.export_checkpoint` to a temporary fp32 file (checked, verified against torch
    when ``verify``), then `quantize_model` from it to ``path`` (verified against that fp32 file);
    the fp32 file is removed either way. ``real``: recordings whose sweeps, but their last
    ``real_holdout``, join the calibration (`real_calibration_drives`). Returns (fp32 `ExportReport`,
    `QuantizeReport`)."""
    from .onnx_export import export_checkpoint

    quantize_scheme(quantize)
    if (export_kwargs.get("form") or "stream") != "stream":
        raise ExportError("--quantize needs the stream form (its calibration feeds the stream state)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".fp32.onnx", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        fp32 = export_checkpoint(checkpoint, tmp, verify=verify, **export_kwargs)
        q = quantize_model(tmp, path, drives=drives, exclude=exclude, verify=verify, calibration=calibration,
                           real=real, real_holdout=real_holdout)
    finally:
        tmp.unlink(missing_ok=True)
    return fp32, q
