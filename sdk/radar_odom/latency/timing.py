"""Time every stage of one model's stream steps, its operators and the numpy reference."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..model_file import STATE_FORMS
from ..odometry.sweep_input import graph_input
from .reference import FFTReference, make_reference, state_to_image, state_to_spectrum
from .stats import _summarise_ops, latency_summary, masker_time, operator_runs, peak_rss_mb
from .sweeps import decode_png, parse_sweep

STAGES = ("png_decode", "sweep_parse", "polar_to_cartesian", "graph", "step", "full")


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
    files: dict = field(default_factory=dict)  # "pipelined" / "serial" -> pipeline.Throughput.as_dict()
    traces: list = field(default_factory=list)  # onnxruntime trace files kept (only with a trace_dir)
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def profile_model(model_path, pngs: list[bytes], *, steps: int = 200, warmup: int = 20, threads: int = 2,
                  reference_steps: int = 30, operator_steps: int = 50, trace_dir=None, name=None,
                  untrained: bool = False, progress_bar: bool = True, echo=None,
                  every_s: float = 8.0, runtime: str = "onnxruntime") -> ModelProfile:
    """Time every stage of ``steps`` stream steps of one model (see the module docstring); ``echo``
    (e.g. print) says when each later phase starts and, every ``every_s`` seconds, that it still runs.
    onnxruntime's trace is kept in ``trace_dir`` only when one is given (tens of MB).
    ``runtime``: one of `radar_odom.runtimes.RUNTIMES` (operators are traced on ``"onnxruntime"`` alone).
    A sweep-form model's *polar→Cartesian* stage is only its feeds' preparation: its graph draws the image."""
    say = echo or (lambda text: None)
    from .._progress import heartbeat, progress
    from ..odometry.odometer import RadarOdometer
    from ..runtimes import load_model

    model = load_model(model_path, runtime, threads)
    info = model.info
    odo = RadarOdometer(model)
    search = info.search
    result = ModelProfile(name or Path(model_path).stem, str(model_path), dict(info.profile.__dict__),
                          search, untrained)
    streaming = info.form in STATE_FORMS and info.profile.mode == "single"
    if not streaming:
        result.notes.append(f"{info.form} form / {info.profile.mode} mode: no spectrum state, "
                            "so no numpy-FFT reference")
    sweep_name = info.inputs[0]
    state = np.zeros(info.state_shape, dtype=np.float32) if streaming else None
    prev_x = None
    times = {s: [] for s in STAGES}
    bar = progress(total=warmup + steps, desc=f"profile {result.name}", unit="step", disable=not progress_bar,
                   interval_s=every_s)
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        img = decode_png(pngs[i % len(pngs)])
        t1 = time.perf_counter()
        scan = parse_sweep(img)
        t2 = time.perf_counter()
        x = graph_input(scan, odo.info)  # the odometer's own conversion (Cartesian or reduced polar)
        t3 = time.perf_counter()
        if streaming:
            feeds = _stream_feeds(info, x, state)
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
        say(f"{result.name}: the same search in numpy (pocketfft), {reference_steps} steps ...")
        with heartbeat(say, f"{result.name}: numpy reference", every_s):
            result.reference = _reference(model, info, pngs, odo, reference_steps, search)
    if operator_steps > 0 and runtime != "onnxruntime":
        result.notes.append(f"{runtime}: operators not traced (onnxruntime's profiler only)")
    elif operator_steps > 0:
        say(f"{result.name}: onnxruntime's profiler, {operator_steps} steps ...")
        with heartbeat(say, f"{result.name}: onnxruntime's profiler", every_s):
            result.operators, result.masker, result.traces = _operators(
                model_path, threads, pngs, odo, info, operator_steps, trace_dir, result.name)
    return result


def _stream_feeds(info, x, state) -> dict:
    """A stream step's feeds: the sweep input (an array, or a sweep-form model's dict of arrays) and the state."""
    return {**(x if isinstance(x, dict) else {info.inputs[0]: x}), info.inputs[-1]: state}


def _stream_states(model, info, pngs, odo, count):
    """(previous state, current state, pose) for ``count`` consecutive steps of a fresh stream."""
    state = np.zeros(info.state_shape, dtype=np.float32)
    for i in range(count + 1):
        out = model.run(_stream_feeds(info, graph_input(parse_sweep(decode_png(pngs[i % len(pngs)])), odo.info), state))
        if i:
            yield state, out["state"], out["pose"][0]
        state = out["state"]


def _reference(model, info, pngs, odo, count, search) -> dict:
    """Graph vs numpy-FFT search on the same masked images: times and pose agreement."""
    p = info.profile
    refs = {"exhaustive": FFTReference(p)}
    if search and (search.get("kind") == "decoupled"
                   or search.get("band_rotations", p.num_rotations) < p.num_rotations):
        refs["same_search"] = make_reference(p, search)
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


def _operators(model_path, threads, pngs, odo, info, steps, trace_dir, name) -> tuple[dict, dict, list]:
    """Operator classes from a separate, traced session (tracing slows the timed one): (operator
    summaries, masker time, [the trace file] when kept in ``trace_dir``, else [])."""
    import re
    import tempfile

    from ..onnx_model import OnnxModel

    tmp = None
    if trace_dir is None:
        tmp = tempfile.TemporaryDirectory()
        trace_dir = tmp.name
    prefix = Path(trace_dir) / ("ort-trace-" + re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-"))  # a plain name
    traced = OnnxModel(model_path, threads=threads, enable_profiling=True, profile_prefix=prefix)
    try:
        if info.form in STATE_FORMS and info.profile.mode == "single":
            for _ in _stream_states(traced, info, pngs, odo, steps):
                pass
        else:
            x = graph_input(parse_sweep(decode_png(pngs[0])), odo.info)
            for _ in range(steps):
                traced.run({n: x for n in info.inputs})
        trace = traced.end_profiling()
        per_run, names = operator_runs(trace)
        return _summarise_ops(per_run, names), masker_time(per_run), ([] if tmp is not None else [str(trace)])
    finally:
        if tmp is not None:
            tmp.cleanup()

