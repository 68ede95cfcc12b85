"""CPU latency of the runtime, per stage and per operator class, with a numpy-FFT reference.

``radar-odom profile`` (`run_profile`) streams simulated sweeps through one exported model per
grid profile and times each stage of a step as the runtime performs it:

* ``png_decode``: ``cv2.imdecode`` of an Oxford-layout sweep PNG (400 × 3779 bytes);
* ``sweep_parse``: header columns → `RadarScan` (timestamps, encoder angles, power / 255);
* ``polar_to_cartesian``: the graph's input (`RadarOdometer`'s own conversion);
* ``graph``: one onnxruntime run (masker, rotations, correlation, soft-argmax);
* ``step`` = polar→Cartesian + graph (what the paper times on its GPU), ``full`` = all four.

Each is summarised as median / p90 / p99 (ms) over the timed steps after a warm-up.
Inside the graph, onnxruntime's own profiler (``SessionOptions.enable_profiling``) is run on a
separate session, its JSON trace parsed and node times grouped by operator class per run
(`operator_profile`), so the timed session is not slowed by tracing.

**Reference** (`FFTReference`): the same search written with numpy's pocketfft (``rfft2`` /
``irfft2``) and OpenCV's bilinear ``warpAffine`` on the *same masked images* — recovered from
the graph's own stream state (the masked sweep's half spectrum) with ``irfft2``. Two variants
are timed: the exhaustive search over every candidate of the profile, and, for models exported
with the fast search (``radar_odom.search`` metadata), the same coarse-to-fine search. The
report gives graph time / reference time. The reference covers the search only (no masker).

**Memory**: peak RSS (``VmHWM``) of the process, and `rss_stream`, which runs a long stream
through `RadarOdometer` in a fresh interpreter (nothing else loaded) and samples ``VmRSS``.

Models: shipped ones by name, ``.onnx`` paths, or for a profile with neither, an untrained
model exported on the fly (needs torch, imported only in a child process; this module never
imports torch).
"""
from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import RadarOdomError

STAGES = ("png_decode", "sweep_parse", "polar_to_cartesian", "graph", "step", "full")
DEFAULT_PROFILES = ("cart-0.8", "cart-0.4", "cart-0.2")
# The paper's Titan Xp times for a full step (its appendix, speed vs accuracy), ms.
PAPER_GPU_MS = {0.8: 11.3, 0.4: 16.9, 0.2: 48.5}
PROFILE_SEED = 4242  # the simulated drive the sweeps come from (content barely matters for speed)


# ============================================================================ small pure helpers
def latency_summary(seconds) -> dict:
    """{"median", "p90", "p99", "mean", "min", "n"} in milliseconds of a list of durations (s)."""
    ms = np.asarray(seconds, dtype=np.float64) * 1e3
    if ms.size == 0:
        return {"median": None, "p90": None, "p99": None, "mean": None, "min": None, "n": 0}
    return {"median": float(np.median(ms)), "p90": float(np.percentile(ms, 90)),
            "p99": float(np.percentile(ms, 99)), "mean": float(ms.mean()), "min": float(ms.min()),
            "n": int(ms.size)}


def _status_kb(field_name: str, text: str | None = None) -> float | None:
    if text is None:
        try:
            text = Path("/proc/self/status").read_text()
        except OSError:
            return None
    for line in text.splitlines():
        if line.startswith(field_name + ":"):
            return float(line.split()[1])
    return None


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MiB (``VmHWM``; ``ru_maxrss`` elsewhere)."""
    kb = _status_kb("VmHWM")
    if kb is None:
        import resource

        kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        if sys.platform == "darwin":  # bytes there, KiB on Linux
            kb /= 1024.0
    return kb / 1024.0


def rss_mb() -> float | None:
    """Current resident memory of this process in MiB (``VmRSS``), None where unknown."""
    kb = _status_kb("VmRSS")
    return None if kb is None else kb / 1024.0


def machine_info(threads: int) -> dict:
    """CPU model, core counts, library versions, threads and the load when the run started."""
    import onnxruntime

    from .onnx_model import physical_cores

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {"cpu": cpu, "logical_cores": os.cpu_count(), "physical_cores": physical_cores(),
            "onnxruntime": onnxruntime.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "threads": int(threads), "load_average": load}


def format_machine(info: dict) -> str:
    load = info.get("load_average")
    tail = f", load average {load[0]:.2f} at start" if load else ""
    return (f"{info['cpu']}, {info['logical_cores']} logical / {info['physical_cores']} physical cores, "
            f"onnxruntime {info['onnxruntime']}, numpy {info['numpy']}, {info['threads']} threads{tail}")


# ============================================================================ onnxruntime trace
# Operator classes of the masker (the U-Net and its pooling/upsampling); onnxruntime fuses
# Conv + Relu into FusedConv on CPU. Everything else in a graph is the search.
MASKER_OPS = frozenset({"Conv", "FusedConv", "Relu", "MaxPool", "AveragePool", "Upsample", "Resize", "Sigmoid"})


def operator_runs(trace_path) -> tuple[dict, dict]:
    """``({op: seconds per run (array)}, {op: set of node names})`` from onnxruntime's JSON trace.

    Node events (``cat == "Node"``, name ``…_kernel_time``) are assigned to the ``model_run``
    event that contains them and summed per operator class (``args.op_name``) and run.
    """
    events = json.loads(Path(trace_path).read_text())
    runs = sorted((e["ts"], e["ts"] + e["dur"]) for e in events
                  if e.get("cat") == "Session" and e.get("name") == "model_run")
    nodes = [e for e in events if e.get("cat") == "Node" and str(e.get("name", "")).endswith("_kernel_time")]
    per_run: dict[str, np.ndarray] = {}
    names: dict[str, set] = {}
    if not runs:
        return per_run, names
    starts = np.array([r[0] for r in runs])
    for e in nodes:
        i = int(np.searchsorted(starts, e["ts"], side="right")) - 1
        if i < 0 or e["ts"] > runs[i][1]:
            continue
        op = e.get("args", {}).get("op_name", "?")
        per_run.setdefault(op, np.zeros(len(runs)))[i] += e["dur"] * 1e-6  # µs → s
        names.setdefault(op, set()).add(e["name"])
    return per_run, names


def masker_time(per_run: dict) -> dict:
    """`latency_summary` of the per-run time of the masker's operator classes (`MASKER_OPS`)."""
    runs = [v for op, v in per_run.items() if op in MASKER_OPS]
    return latency_summary(np.sum(runs, axis=0) if runs else [])


def operator_profile(trace_path) -> dict:
    """Per operator class, the time per run inside the graph (see `operator_runs`).

    Returns ``{op: {"median", "p90", "p99", "mean", "share", "nodes"}}`` (ms per run; share of
    the summed node time), sorted by mean time, descending.
    """
    return _summarise_ops(*operator_runs(trace_path))


def _summarise_ops(per_run: dict, names: dict) -> dict:
    total = sum(v.sum() for v in per_run.values())
    out = {}
    for op, v in sorted(per_run.items(), key=lambda kv: -kv[1].sum()):
        s = latency_summary(v)
        out[op] = {k: s[k] for k in ("median", "p90", "p99", "mean")}
        out[op]["share"] = float(v.sum() / total) if total else 0.0
        out[op]["nodes"] = len(names[op])
    return out


# ============================================================================ numpy reference
def _rotation_matrix(yaw_rad: float, width_px: int) -> np.ndarray:
    """2×3 ``warpAffine`` map (with WARP_INVERSE_MAP) from output to input pixel (u=col, v=row)
    that samples ``S(R(yaw)ᵀ p)`` about the image centre: the graph's rotation convention
    (x = cW − row forward, y = col − cW right)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    cw = (width_px - 1) / 2
    return np.array([[c, s, cw * (1 - c - s)], [-s, c, cw * (1 - c + s)]], dtype=np.float64)


class FFTReference:
    """The correlative search of a `GridProfile` in numpy (pocketfft) and OpenCV.

    ``search(prev_spectrum, cur_image)`` takes the previous masked image's half spectrum
    (complex [W, W//2+1], i.e. the stream state) and the current masked image [W, W] and returns
    ``(pose [3], covariance [3, 3])`` by the profile's soft-argmax. With ``search_settings``
    (the ``radar_odom.search`` metadata of a fast-search model) it runs the same coarse-to-fine
    search: a yaw picked on spectra cropped to ``W / coarse_factor`` px, then the band of
    ``2b + 1`` yaws and yaw 0 at full resolution; otherwise every candidate.
    """

    def __init__(self, profile, search_settings: dict | None = None):
        self.profile = profile
        self.width = profile.width_px
        self.n = profile.translation_cells
        self.yaws = np.asarray(profile.rotations_rad, dtype=np.float64)
        offsets = np.arange(-self.n, self.n + 1) * profile.resolution_m
        self.trans = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1)  # [N, N, 2]
        self.settings = search_settings if search_settings and search_settings.get(
            "band_rotations", len(self.yaws)) < len(self.yaws) else None

    def _rotated(self, image: np.ndarray, yaws) -> np.ndarray:
        import cv2

        w = image.shape[-1]
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        return np.stack([cv2.warpAffine(image, _rotation_matrix(y, w), (w, w), flags=flags,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
                         for y in yaws])

    @staticmethod
    def _volume(prev_spectrum, rotated, n):
        """[K, N, N] correlation window, the graph's layout (see correlation.py)."""
        w = rotated.shape[-1]
        full = np.fft.irfft2(np.conj(prev_spectrum)[None] * np.fft.rfft2(rotated), s=(w, w))
        return np.roll(full, (n, n), axis=(-2, -1))[:, : 2 * n + 1, : 2 * n + 1][:, :, ::-1]

    def _crop(self, spectrum, low):
        half = low // 2
        rows = np.r_[0:half, self.width - half:self.width]
        out = spectrum[rows, : half + 1].copy()
        out[half, :] = 0
        out[:, half] = 0
        return out

    def band(self, prev_spectrum, cur_spectrum) -> np.ndarray:
        """Indices of the yaws evaluated at full resolution."""
        k = len(self.yaws)
        if self.settings is None:
            return np.arange(k)
        f, stride = int(self.settings["coarse_factor"]), int(self.settings["coarse_stride"])
        size = int(self.settings["band_rotations"])
        low = self.width // f
        centre = k // 2
        idx = np.array(sorted({*range(centre, -1, -stride), *range(centre, k, stride)}))
        cur_low = np.fft.irfft2(self._crop(cur_spectrum, low), s=(low, low)).astype(np.float32)
        rotated = self._rotated(cur_low, self.yaws[idx])
        vol = self._volume(self._crop(prev_spectrum, low), rotated, max(1, math.ceil(self.n / f)))
        norm = np.sqrt((rotated.astype(np.float64) ** 2).reshape(len(idx), -1).sum(axis=1) + 1e-12)
        best = int(idx[np.argmax(vol.reshape(len(idx), -1).max(axis=1) / norm)])
        start = min(max(best - size // 2, 0), k - size)
        return np.arange(start, start + size)

    def search(self, prev_spectrum: np.ndarray, cur_image: np.ndarray):
        cur_image = np.ascontiguousarray(cur_image, dtype=np.float32)
        cur_spectrum = np.fft.rfft2(cur_image) if self.settings is not None else None
        idx = self.band(prev_spectrum, cur_spectrum)
        # the fast graph also scores yaw 0 (the unrotated image) whatever the band
        idx = np.union1d(idx, [len(self.yaws) // 2])
        rotated = self._rotated(cur_image, self.yaws[idx])
        rotated[np.flatnonzero(idx == len(self.yaws) // 2)] = cur_image  # yaw 0: the image itself
        vol = self._volume(prev_spectrum, rotated, self.n)
        cand = np.concatenate([np.broadcast_to(self.trans, (len(idx), *self.trans.shape)),
                               np.broadcast_to(self.yaws[idx][:, None, None, None],
                                               (len(idx), *self.trans.shape[:2], 1))], axis=-1)
        cand = cand.reshape(-1, 3)
        flat = vol.reshape(-1).astype(np.float64)

        def weights(beta):
            z = beta * flat
            e = np.exp(z - z.max())
            return e / e.sum()

        w = weights(self.profile.beta_pose)
        pose = w @ cand
        wc = weights(self.profile.beta_cov)
        centred = cand - wc @ cand
        # the same quantisation floor the graph adds (GridProfile.covariance_floor)
        cov = (centred * wc[:, None]).T @ centred + np.diag(self.profile.covariance_floor)
        return pose, cov


def state_to_image(state: np.ndarray, width_px: int) -> np.ndarray:
    """The masked image [W, W] whose half spectrum is the stream state [1, 2, W, W//2+1]."""
    spec = state[0, 0].astype(np.float64) + 1j * state[0, 1].astype(np.float64)
    return np.fft.irfft2(spec, s=(width_px, width_px)).astype(np.float32)


def state_to_spectrum(state: np.ndarray) -> np.ndarray:
    return state[0, 0].astype(np.float64) + 1j * state[0, 1].astype(np.float64)


# ============================================================================ sweeps
def simulated_pngs(count: int, seed: int = PROFILE_SEED, scenario: str = "urban") -> list[bytes]:
    """``count`` simulated sweeps encoded as Oxford-layout PNG bytes (what a recording holds)."""
    import cv2

    from .formats.oxford import scan_to_image
    from .sim import simulate_drive

    out = []
    for frame in simulate_drive(seed, count, scenario):
        ok, buf = cv2.imencode(".png", scan_to_image(frame.scan))
        if not ok:
            raise RadarOdomError("OpenCV could not encode a simulated sweep as PNG")
        out.append(buf.tobytes())
    return out


def decode_png(data: bytes) -> np.ndarray:
    import cv2

    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RadarOdomError("a sweep PNG could not be decoded")
    return img


def parse_sweep(img: np.ndarray, source: str = "profile"):
    """Oxford-layout pixels → `RadarScan` (the reader's own parsing)."""
    from .formats._layout import scan_from_header_image
    from .scan import OXFORD_RANGE_RESOLUTION_M

    return scan_from_header_image(img, source, use_valid_column=True,
                                  range_resolution_m=OXFORD_RANGE_RESOLUTION_M, range_offset_m=0.0)


# ============================================================================ one model
@dataclass
class ModelProfile:
    """What `profile_model` measured for one model."""

    name: str
    path: str
    profile: dict
    search: dict | None
    untrained: bool
    stages: dict = field(default_factory=dict)  # stage -> latency_summary
    operators: dict = field(default_factory=dict)  # op class -> summary
    reference: dict = field(default_factory=dict)
    masker: dict = field(default_factory=dict)  # latency_summary of the masker's operators (traced)
    peak_rss_mb: float | None = None
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def profile_model(model_path, pngs: list[bytes], *, steps: int = 200, warmup: int = 20, threads: int = 2,
                  reference_steps: int = 30, operator_steps: int = 50, trace_dir=None, name=None,
                  untrained: bool = False, progress_bar: bool = True) -> ModelProfile:
    """Time every stage of ``steps`` stream steps of one model (see the module docstring)."""
    from ._progress import progress
    from .odometer import RadarOdometer
    from .onnx_model import OnnxModel

    model = OnnxModel(model_path, threads=threads)
    info = model.info
    odo = RadarOdometer(model)
    search = json.loads(model.session.get_modelmeta().custom_metadata_map.get("radar_odom.search", "null"))
    result = ModelProfile(name or Path(model_path).stem, str(model_path), dict(info.profile.__dict__),
                          search, untrained)
    streaming = info.form == "stream" and info.profile.mode == "single"
    if not streaming:
        result.notes.append(f"{info.form} form / {info.profile.mode} mode: no spectrum state, "
                            "so no numpy-FFT reference")
    sweep_name, state_name = info.inputs[0], info.inputs[1]
    state = np.zeros(info.state_shape, dtype=np.float32) if streaming else None
    prev_x = None
    times = {s: [] for s in STAGES}
    bar = progress(total=warmup + steps, desc=f"profile {result.name}", unit="step", disable=not progress_bar)
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        img = decode_png(pngs[i % len(pngs)])
        t1 = time.perf_counter()
        scan = parse_sweep(img)
        t2 = time.perf_counter()
        x = odo._sweep_input(scan)  # the odometer's own conversion (Cartesian or reduced polar)
        t3 = time.perf_counter()
        if streaming:
            feeds = {sweep_name: x, state_name: state}
        else:  # pair form, or a dual-mode stream whose state is the previous sweep
            feeds = {info.inputs[0]: x if prev_x is None else prev_x, info.inputs[1]: x}
            if info.form == "stream":
                feeds = {sweep_name: x, info.inputs[1]: x if prev_x is None else prev_x}
        out = model.run(feeds)
        t4 = time.perf_counter()
        if streaming:
            state = out["state"]
        prev_x = x
        if i >= warmup:
            for stage, dt in (("png_decode", t1 - t0), ("sweep_parse", t2 - t1), ("polar_to_cartesian", t3 - t2),
                              ("graph", t4 - t3), ("step", t4 - t2), ("full", t4 - t0)):
                times[stage].append(dt)
        bar.update(1)
    bar.close()
    result.stages = {s: latency_summary(v) for s, v in times.items()}
    result.peak_rss_mb = peak_rss_mb()
    if streaming and reference_steps > 0:
        result.reference = _reference(model, info, pngs, odo, reference_steps, search)
    if operator_steps > 0:
        result.operators, result.masker = _operators(model_path, threads, pngs, odo, info, operator_steps,
                                                     trace_dir, result.name)
    return result


def _stream_states(model, info, pngs, odo, count):
    """(previous state, current state, pose) for ``count`` consecutive steps of a fresh stream."""
    state = np.zeros(info.state_shape, dtype=np.float32)
    for i in range(count + 1):
        out = model.run({info.inputs[0]: odo._sweep_input(parse_sweep(decode_png(pngs[i % len(pngs)]))),
                         info.inputs[1]: state})
        if i:
            yield state, out["state"], out["pose"][0]
        state = out["state"]


def _reference(model, info, pngs, odo, count, search) -> dict:
    """Graph vs numpy-FFT search on the same masked images: times and pose agreement."""
    p = info.profile
    refs = {"exhaustive": FFTReference(p)}
    if search and search.get("band_rotations", p.num_rotations) < p.num_rotations:
        refs["same_search"] = FFTReference(p, search)
    times = {k: [] for k in refs}
    diffs = {k: [] for k in refs}
    for prev, cur, pose in _stream_states(model, info, pngs, odo, count):
        prev_spec, cur_img = state_to_spectrum(prev), state_to_image(cur, p.width_px)
        for k, ref in refs.items():
            t = time.perf_counter()
            ref_pose, _ = ref.search(prev_spec, cur_img)
            times[k].append(time.perf_counter() - t)
            diffs[k].append(np.abs(ref_pose - pose))
    out = {}
    for k in refs:
        d = np.array(diffs[k])
        out[k] = {"time": latency_summary(times[k]),
                  "pose_diff_median": {"x_m": float(np.median(d[:, 0])), "y_m": float(np.median(d[:, 1])),
                                       "yaw_rad": float(np.median(d[:, 2]))}}
    return out


def _operators(model_path, threads, pngs, odo, info, steps, trace_dir, name) -> dict:
    """Operator classes from a separate, traced session (tracing slows the timed one)."""
    import tempfile

    from .onnx_model import OnnxModel

    tmp = None
    if trace_dir is None:
        tmp = tempfile.TemporaryDirectory()
        trace_dir = tmp.name
    prefix = Path(trace_dir) / f"ort-trace-{name}"
    traced = OnnxModel(model_path, threads=threads, enable_profiling=True, profile_prefix=prefix)
    try:
        if info.form == "stream" and info.profile.mode == "single":
            for _ in _stream_states(traced, info, pngs, odo, steps):
                pass
        else:
            x = odo._sweep_input(parse_sweep(decode_png(pngs[0])))
            for _ in range(steps):
                traced.run({n: x for n in info.inputs})
        per_run, names = operator_runs(traced.end_profiling())
        return _summarise_ops(per_run, names), masker_time(per_run)
    finally:
        if tmp is not None:
            tmp.cleanup()


# ============================================================================ memory of a long stream
RSS_CHILD = r"""
import json, sys
from radar_odom.profiling import rss_stream_here
print(json.dumps(rss_stream_here(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]))))
"""


def rss_stream(model_path, steps: int = 1000, threads: int = 2, every: int = 50) -> dict:
    """`rss_stream_here` in a fresh interpreter, so that nothing else counts towards its RSS."""
    proc = subprocess.run([sys.executable, "-c", RSS_CHILD, str(model_path), str(steps), str(threads), str(every)],
                          capture_output=True, text=True, check=False)
    if proc.returncode:
        raise RadarOdomError(f"the RSS stream of {model_path} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def rss_stream_here(model_path, steps: int, threads: int = 2, every: int = 50, distinct: int = 16) -> dict:
    """Run ``steps`` sweeps through `RadarOdometer` (PNG decode → parse → step), sampling
    ``VmRSS`` every ``every`` steps. ``distinct`` simulated sweeps are cycled with their
    timestamps moved on, so the stream is continuous and holds only PNG bytes in memory.

    Returns ``{"steps", "samples": [[step, MiB], ...], "peak_mb", "growth_mb"}`` where
    ``growth_mb`` is the RSS change from the first sample after 10 % of the stream to the end.
    """
    from dataclasses import replace

    from .odometer import RadarOdometer

    pngs = simulated_pngs(distinct, seed=PROFILE_SEED + 1)
    odo = RadarOdometer(model_path, threads=threads, max_gap_s=10.0)
    period_us = int(np.median(np.diff([parse_sweep(decode_png(b)).timestamp_us for b in pngs[:2]]))) or 250_000
    samples = []
    for i in range(steps):
        scan = parse_sweep(decode_png(pngs[i % distinct]))
        lap = i // distinct
        if lap:
            scan = replace(scan, timestamps_us=scan.timestamps_us + lap * distinct * period_us)
        odo.step(scan)
        if (i + 1) % every == 0 or i == 0:
            samples.append([i + 1, rss_mb()])
    start = next((s for s in samples if s[0] >= steps // 10), samples[0])
    return {"steps": steps, "every": every, "samples": samples, "peak_mb": peak_rss_mb(),
            "growth_mb": float(samples[-1][1] - start[1]), "growth_from_step": start[0]}


# ============================================================================ models to profile
EXPORT_CHILD = r"""
import sys, torch
from radar_odom.profiles import get_profile
from radar_odom_export.model import MaskedCorrelator
torch.manual_seed(0)
model = MaskedCorrelator(get_profile(sys.argv[1]), masking="learned").eval()
if sys.argv[3] == "fast":
    from radar_odom_export.fast_search import export_fast
    export_fast(model, sys.argv[2], verify=False, training_data="untrained (radar-odom profile)")
else:
    from radar_odom_export.onnx_export import export_model
    export_model(model, sys.argv[2], verify=False, training_data="untrained (radar-odom profile)")
"""


def untrained_model(profile_name: str, out_dir, search: str = "fast") -> Path:
    """Export (once; cached in ``out_dir``) an untrained learned-mask model of ``profile_name``.

    Runs in a child interpreter: this needs torch (``pip install "radar-odom[export]"``), and
    keeping it out of this process keeps the memory figures honest.
    """
    path = Path(out_dir) / f"untrained-{profile_name}-{search}.onnx"
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([sys.executable, "-c", EXPORT_CHILD, profile_name, str(path), search],
                          capture_output=True, text=True, check=False)
    if proc.returncode:
        if "No module named 'torch'" in proc.stderr or "No module named 'radar_odom_export'" in proc.stderr:
            raise RadarOdomError(
                f"no model given for {profile_name} and torch is not installed to export an untrained "
                'one: pass --models NAME|PATH.onnx, or pip install "radar-odom[export]"')
        raise RadarOdomError(f"exporting an untrained {profile_name} model failed:\n{proc.stderr[-2000:]}")
    return path


def resolve_models(models, profiles, out_dir, search: str = "fast", echo=print) -> list[tuple[str, Path, bool]]:
    """(label, path, untrained) per model: the given ones (names or paths), then for each of
    ``profiles`` not covered by them (same resolution and width) the shipped model of that name,
    or failing that an untrained export."""
    from .onnx_model import ModelInfo
    from .pretrained import pretrained, pretrained_names, resolve_model
    from .profiles import get_profile

    chosen, covered = [], set()

    def add(label, path, untrained):
        prof = _read_profile(path, ModelInfo)
        chosen.append((label, Path(path), untrained))
        covered.add((prof.resolution_m, prof.width_px))

    for spec in models or ():
        add(Path(spec).stem if spec.endswith(".onnx") else spec, resolve_model(spec), False)
    shipped = set(pretrained_names())
    for name in profiles or ():
        p = get_profile(name)
        if (p.resolution_m, p.width_px) in covered:
            continue
        if name in shipped:
            add(name, pretrained(name), False)
            continue
        cached = Path(out_dir) / "models" / f"untrained-{name}-{search}.onnx"
        echo(f"{name}: no model given or shipped; " + ("using the untrained export in " + str(cached)
             if cached.is_file() else f"exporting an untrained one ({search} search; needs torch) ..."))
        add(f"{name} (untrained)", untrained_model(name, Path(out_dir) / "models", search), True)
    return chosen


def _read_profile(path, model_info_cls):
    """The `GridProfile` in a model's metadata (a session without graph optimisation: cheap)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    return model_info_cls.from_metadata(dict(sess.get_modelmeta().custom_metadata_map), str(path)).profile


# ============================================================================ the whole run
def run_profile(models=(), profiles=DEFAULT_PROFILES, *, threads: int | None = None, steps: int = 200,
                warmup: int = 20, reference_steps: int = 30, operator_steps: int = 50, rss_steps: int = 0,
                rss_profile: str = "cart-0.4", search: str = "fast", out_dir="radar-odom-profile",
                distinct_sweeps: int = 24, command: str | None = None, echo=print, progress_bar=True) -> dict:
    """Profile every model (see `resolve_models`), write ``profile.json`` and ``profile.md`` in
    ``out_dir``, and return the report dictionary."""
    from .onnx_model import physical_cores

    if steps < 1 or warmup < 0:
        raise ValueError("steps must be >= 1 and warmup >= 0")
    threads = int(threads or physical_cores())
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    machine = machine_info(threads)
    echo(f"machine: {format_machine(machine)}")
    chosen = resolve_models(models, profiles, out_dir, search=search, echo=echo)
    echo(f"simulating {distinct_sweeps} sweeps (seed {PROFILE_SEED}) ...")
    pngs = simulated_pngs(distinct_sweeps)
    results = []
    for label, path, untrained in chosen:
        r = profile_model(path, pngs, steps=steps, warmup=warmup, threads=threads,
                          reference_steps=reference_steps, operator_steps=operator_steps,
                          trace_dir=out_dir, name=label, untrained=untrained, progress_bar=progress_bar)
        echo(summary_line(r))
        results.append(r.to_dict())
    report = {"command": command, "machine": machine,
              "settings": {"steps": steps, "warmup": warmup, "threads": threads, "reference_steps": reference_steps,
                           "operator_steps": operator_steps, "distinct_sweeps": distinct_sweeps,
                           "sweeps": f"simulated, seed {PROFILE_SEED}, urban"},
              "models": results, "rss_stream": None}
    if rss_steps:
        target = next(((lbl, p) for (lbl, p, _), r in zip(chosen, results)
                       if r["profile"]["name"] == rss_profile or lbl.startswith(rss_profile)), None)
        if target is None:
            echo(f"no {rss_profile} model among the profiled ones: no RSS stream")
        else:
            echo(f"RSS: {rss_steps} steps of {target[0]} through RadarOdometer in a fresh process ...")
            report["rss_stream"] = {"model": target[0], **rss_stream(target[1], rss_steps, threads)}
            rs = report["rss_stream"]
            echo(f"RSS: peak {rs['peak_mb']:.0f} MiB, {rs['growth_mb']:+.1f} MiB from step "
                 f"{rs['growth_from_step']} to {rs['steps']}")
    (out_dir / "profile.json").write_text(json.dumps(report, indent=2))
    (out_dir / "profile.md").write_text(markdown_report(report))
    echo(f"wrote {out_dir / 'profile.json'} and {out_dir / 'profile.md'}")
    return report


def _ms(s: dict | None, with_tail: bool = True) -> str:
    if not s or s.get("median") is None:
        return "–"
    if not with_tail:
        return f"{s['median']:.1f}"
    return f"{s['median']:.1f} / {s['p90']:.1f} / {s['p99']:.1f}"


def _ratio(r: dict, key: str) -> str:
    ref = (r.get("reference") or {}).get(key)
    if not ref:
        return "–"
    return f"{r['stages']['graph']['median'] / ref['time']['median']:.2f} ({ref['time']['median']:.1f} ms)"


def _search_ratio(r: dict) -> str:
    """(graph − masker operators) / numpy same-search reference: both start from masked images."""
    ref = (r.get("reference") or {}).get("same_search") or (r.get("reference") or {}).get("exhaustive")
    masker = (r.get("masker") or {}).get("median")
    if not ref or masker is None:
        return "–"
    search = r["stages"]["graph"]["median"] - masker
    return f"{search / ref['time']['median']:.2f} ({search:.1f} ms)"


def _search_label(r: dict) -> str:
    s = r.get("search")
    if not s:
        return f"exhaustive ({_num_rotations(r['profile'])} yaws)"
    return (f"coarse 1/{s['coarse_factor']} every {s['coarse_stride']}, band {s['band_rotations']} yaws"
            + ("" if s.get("rotation", "polar") == "polar" else f", {s['rotation']}"))


def _num_rotations(profile: dict) -> int:
    return 2 * int(round(profile["rotation_range_rad"] / profile["rotation_step_rad"])) + 1


def summary_line(r: ModelProfile) -> str:
    g, st = r.stages["graph"], r.stages["step"]
    res = r.profile["resolution_m"]
    paper = PAPER_GPU_MS.get(round(res, 3))
    tail = f" (paper GPU {paper} ms)" if paper else ""
    return (f"{r.name}: step {st['median']:.1f} ms median{tail}, graph {g['median']:.1f} ms, "
            f"p2c {r.stages['polar_to_cartesian']['median']:.1f} ms, decode {r.stages['png_decode']['median']:.1f} ms, "
            f"peak RSS {r.peak_rss_mb:.0f} MiB")


def markdown_report(report: dict) -> str:
    """The report as markdown: machine line, latency table, operator classes, memory."""
    st = report["settings"]
    lines = []
    if report.get("command"):
        lines += [f"Command: `{report['command']}`", ""]
    lines += [f"Machine: {format_machine(report['machine'])}.",
              f"Sweeps: {st['sweeps']} ({st['distinct_sweeps']} distinct, cycled). Times in ms as "
              f"median / p90 / p99 over {st['steps']} steps after {st['warmup']} warm-up steps; "
              f"numpy-FFT references over {st['reference_steps']} steps. The references search the masked "
              "images (no masker); *search only* is the graph's median minus its masker operators' median "
              f"({', '.join(sorted(MASKER_OPS))}) from the traced runs. Process peak RSS is cumulative over the "
              "models profiled so far; the memory line below is one model alone.", "",
              "| model | grid | search | PNG decode | sweep parse | polar→Cartesian | graph | step (p→C + graph) "
              "| paper GPU step | graph / numpy-FFT exhaustive | graph / numpy-FFT same search "
              "| search only / numpy-FFT same search | process peak RSS MiB |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["models"]:
        p, s = r["profile"], r["stages"]
        paper = PAPER_GPU_MS.get(round(p["resolution_m"], 3))
        lines.append(
            f"| {r['name']} | {p['resolution_m']} m × {p['width_px']} px | {_search_label(r)} | {_ms(s['png_decode'])} "
            f"| {_ms(s['sweep_parse'])} | {_ms(s['polar_to_cartesian'])} | {_ms(s['graph'])} | {_ms(s['step'])} "
            f"| {paper if paper else '–'} | {_ratio(r, 'exhaustive')} | {_ratio(r, 'same_search')} "
            f"| {_search_ratio(r)} | {r['peak_rss_mb']:.0f} |")
    for r in report["models"]:
        ops = r.get("operators") or {}
        if not ops:
            continue
        lines += ["", f"Operators in the graph of {r['name']} (ms per run, median / p90 / p99; share of node time):", "",
                  "| operator | time | share | nodes |", "|---|---|---|---|"]
        for op, v in list(ops.items())[:10]:
            lines.append(f"| {op} | {_ms(v)} | {100 * v['share']:.0f} % | {v['nodes']} |")
    agreement = [(r["name"], k, ref["pose_diff_median"]) for r in report["models"]
                 for k, ref in (r.get("reference") or {}).items()]
    if agreement:
        lines += ["", "Pose agreement, graph vs numpy-FFT reference (median |Δ| over the reference steps):", ""]
        lines += [f"- {name}, {k.replace('_', ' ')}: x {d['x_m']:.3f} m, y {d['y_m']:.3f} m, "
                  f"yaw {math.degrees(d['yaw_rad']):.3f}°" for name, k, d in agreement]
    rs = report.get("rss_stream")
    if rs:
        lines += ["", f"Memory: {rs['steps']} steps of {rs['model']} through `RadarOdometer` in a fresh process: "
                      f"peak RSS {rs['peak_mb']:.0f} MiB; RSS {rs['growth_mb']:+.1f} MiB from step "
                      f"{rs['growth_from_step']} to the end (sampled every {rs.get('every', '?')} steps)."]
    untrained = [r["name"] for r in report["models"] if r.get("untrained")]
    if untrained:
        lines += ["", f"Untrained models (exported on the fly, timing only): {', '.join(untrained)}."]
    return "\n".join(lines) + "\n"
