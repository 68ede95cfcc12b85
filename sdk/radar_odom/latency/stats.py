"""Latency summaries, process memory, machine facts and onnxruntime trace parsing."""
from __future__ import annotations

import json
import os
import platform
import sys
from pathlib import Path

import numpy as np


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

    from ..onnx_model import physical_cores

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

