"""`run_profile`: the whole ``radar-odom profile`` run and its markdown report."""
from __future__ import annotations

import json
import math
from pathlib import Path

from .columns import FILE_COLUMNS, LATENCY_COLUMNS, legend
from .files import file_throughput
from .memory import rss_stream
from .models import resolve_models
from .stats import MASKER_OPS, format_machine, machine_info
from .sweeps import PROFILE_SEED, simulated_pngs
from .timing import ModelProfile, profile_model

DEFAULT_PROFILES = ("cart-0.8", "cart-0.4")  # the shipped models; cart-0.2 (untrained export) on request
PROGRESS_EVERY_S = 8.0  # a line at least this often (a step or a tqdm redraw later: within 10 s)
# The paper's Titan Xp times for a full step (its appendix, speed vs accuracy), ms.
PAPER_GPU_MS = {0.8: 11.3, 0.4: 16.9, 0.2: 48.5}


def run_profile(
    models=(),
    profiles=DEFAULT_PROFILES,
    *,
    threads: int | None = None,
    steps: int = 200,
    warmup: int = 20,
    reference_steps: int = 30,
    operator_steps: int = 50,
    rss_steps: int = 0,
    rss_profile: str = "cart-0.4",
    search: str = "fast",
    out_dir="radar-odom-profile",
    distinct_sweeps: int = 24,
    file_sweeps: int = 100,
    command: str | None = None,
    echo=print,
    progress_bar=True,
    keep_traces: bool = False,
    runtime: str = "onnxruntime",
) -> dict:
    """Profile every model (see `resolve_models`), write ``profile.json`` and ``profile.md`` in
    ``out_dir`` (and onnxruntime's traces only with ``keep_traces``), and return the report
    dictionary. Every phase says when it starts and at least every `PROGRESS_EVERY_S` while it runs.
    ``runtime``: one of `radar_odom.runtimes.RUNTIMES` (the stream steps and the numpy
    reference; operators and file throughput are onnxruntime's only)."""
    from .._progress import heartbeat
    from ..errors import ConfigError
    from ..onnx_model import physical_cores

    counts = {"steps": (steps, 1), "warmup": (warmup, 0), "reference_steps": (reference_steps, 0),
              "operator_steps": (operator_steps, 0), "rss_steps": (rss_steps, 0), "file_sweeps": (file_sweeps, 0)}
    for name, (value, least) in counts.items():  # named as `radar-odom profile` names them
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            flag = "--" + name.replace("_", "-")
            raise ConfigError(f"{flag} must be a whole number ≥ {least}, got {value!r}"
                              + (" (a profile times at least one step)" if name == "steps" else ""))
    threads = int(threads or physical_cores())
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    machine = machine_info(threads)
    echo(f"machine: {format_machine(machine)}")
    with heartbeat(echo, "choosing the models", PROGRESS_EVERY_S):
        chosen = resolve_models(models, profiles, out_dir, search=search, echo=echo)
    written = [path for _, path, untrained in chosen if untrained]  # untrained exports land in out_dir
    echo(f"simulating {distinct_sweeps} sweeps (seed {PROFILE_SEED}) ...")
    with heartbeat(echo, "simulating sweeps", PROGRESS_EVERY_S):
        pngs = simulated_pngs(distinct_sweeps)
    results = []
    for label, path, untrained in chosen:
        r = profile_model(
            path,
            pngs,
            steps=steps,
            warmup=warmup,
            threads=threads,
            reference_steps=reference_steps,
            operator_steps=operator_steps,
            trace_dir=out_dir if keep_traces else None,
            name=label,
            untrained=untrained,
            progress_bar=progress_bar,
            echo=echo,
            every_s=PROGRESS_EVERY_S,
            runtime=runtime,
        )
        written += r.traces
        if file_sweeps > 0 and runtime == "onnxruntime":
            echo(f"{label}: {file_sweeps} sweeps from PNG files, pipelined and serial ...")
            with heartbeat(echo, f"{label}: sweep files", PROGRESS_EVERY_S):
                r.files = file_throughput(path, pngs, sweeps=file_sweeps, threads=threads)
        echo(summary_line(r))
        results.append(r.to_dict())
    report = {
        "command": command,
        "machine": machine,
        "settings": {
            "steps": steps,
            "warmup": warmup,
            "threads": threads,
            "runtime": runtime,
            "reference_steps": reference_steps,
            "operator_steps": operator_steps,
            "distinct_sweeps": distinct_sweeps,
            "file_sweeps": file_sweeps,
            "sweeps": f"simulated, seed {PROFILE_SEED}, urban",
        },
        "models": results,
        "rss_stream": None,
    }
    if rss_steps:
        target = next(
            (
                (lbl, p)
                for (lbl, p, _), r in zip(chosen, results)
                if r["profile"]["name"] == rss_profile or lbl.startswith(rss_profile)
            ),
            None,
        )
        if target is None:
            echo(f"no {rss_profile} model among the profiled ones: no RSS stream")
        else:
            echo(f"RSS: {rss_steps} steps of {target[0]} through RadarOdometer in a fresh process ...")
            with heartbeat(echo, "RSS stream", PROGRESS_EVERY_S):
                report["rss_stream"] = {"model": target[0], **rss_stream(target[1], rss_steps, threads)}
            rs = report["rss_stream"]
            echo(
                f"RSS: peak {rs['peak_mb']:.0f} MiB, {rs['growth_mb']:+.1f} MiB from step "
                f"{rs['growth_from_step']} to {rs['steps']}"
            )
    (out_dir / "profile.json").write_text(json.dumps(report, indent=2))
    (out_dir / "profile.md").write_text(markdown_report(report))
    named = ", ".join(str(p) for p in written)
    echo(f"wrote {out_dir / 'profile.json'} and {out_dir / 'profile.md'}" + (f"; and {named}" if named else ""))
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
    if s.get("kind") == "decoupled":
        angles = round(math.pi * s.get("angle_oversample", 1) / r["profile"]["rotation_step_rad"])
        return f"decoupled ({s['radii']} rings × {angles} angles)"
    return f"coarse 1/{s['coarse_factor']} every {s['coarse_stride']}, band {s['band_rotations']} yaws" + (
        "" if s.get("rotation", "polar") == "polar" else f", {s['rotation']}"
    )


def _num_rotations(profile: dict) -> int:
    return 2 * int(round(profile["rotation_range_rad"] / profile["rotation_step_rad"])) + 1


def summary_line(r: ModelProfile) -> str:
    """One printed line per model: the timed steps' medians (step = polar→Cartesian + graph), then
    the separate end-to-end stream over files (sweeps/s and its ms per sweep), with a note where the
    two disagree (the machine's load changed between them: a stream cannot beat its own steps)."""
    g, st = r.stages["graph"], r.stages["step"]
    res = r.profile["resolution_m"]
    paper = PAPER_GPU_MS.get(round(res, 3))
    tail = f" (paper GPU {paper} ms)" if paper else ""
    return (
        f"{r.name}: timed steps, medians: step {st['median']:.1f} ms{tail} = polar→Cartesian "
        f"{r.stages['polar_to_cartesian']['median']:.1f} ms + graph {g['median']:.1f} ms; PNG decode "
        f"{r.stages['png_decode']['median']:.1f} ms; peak RSS {r.peak_rss_mb:.0f} MiB"
        + _files_tail(r.files, st["median"])
    )


def _files_tail(files: dict, step_median_ms: float | None = None) -> str:
    f = (files or {}).get("pipelined")
    if not f:
        return ""
    per_sweep = 1e3 * f["wall_per_sweep_s"]
    text = (f"; files (a separate stream): {f['sweeps_per_s']:.1f} sweeps/s pipelined = {per_sweep:.1f} ms per sweep, "
            f"wall / max(read, step) {f['ratio']:.2f}") + (
        f" (serial {files['serial']['ratio']:.2f})" if files.get("serial") else "")
    if step_median_ms and per_sweep < 0.9 * step_median_ms:
        text += (f" [faster than the timed steps' {step_median_ms:.1f} ms: the machine's load changed between the "
                 "two; compare figures within one of them]")
    return text


def markdown_report(report: dict) -> str:
    """The report as markdown: machine line, latency table, operator classes, memory."""
    st = report["settings"]
    lines = []
    if report.get("command"):
        lines += [f"Command: `{report['command']}`", ""]
    lines += [
        f"Machine: {format_machine(report['machine'])}.",
        f"Runtime: {st.get('runtime', 'onnxruntime')}. "
        f"Sweeps: {st['sweeps']} ({st['distinct_sweeps']} distinct, cycled). Times in ms as "
        f"median / p90 / p99 over {st['steps']} steps after {st['warmup']} warm-up steps; "
        f"numpy-FFT references over {st['reference_steps']} steps. The references search the masked "
        "images (no masker); *search only* is the graph's median minus its masker operators' median "
        f"({', '.join(sorted(MASKER_OPS))}) from the traced runs. Process peak RSS is cumulative over the "
        "models profiled so far; the memory line below is one model alone.",
        "",
        "| " + " | ".join(head for head, _ in LATENCY_COLUMNS) + " |",
        "|" + "---|" * len(LATENCY_COLUMNS),
    ]
    for r in report["models"]:
        p, s = r["profile"], r["stages"]
        paper = PAPER_GPU_MS.get(round(p["resolution_m"], 3))
        lines.append(
            f"| {r['name']} | {p['resolution_m']} m × {p['width_px']} px | {_search_label(r)} | {_ms(s['png_decode'])} "
            f"| {_ms(s['sweep_parse'])} | {_ms(s['polar_to_cartesian'])} | {_ms(s['graph'])} | {_ms(s['step'])} "
            f"| {paper if paper else '–'} | {_ratio(r, 'exhaustive')} | {_ratio(r, 'same_search')} "
            f"| {_search_ratio(r)} | {r['peak_rss_mb']:.0f} |"
        )
    for r in report["models"]:
        ops = r.get("operators") or {}
        if not ops:
            continue
        lines += [
            "",
            f"Operators in the graph of {r['name']} (ms per run, median / p90 / p99; share of node time):",
            "",
            "| operator | time | share | nodes |",
            "|---|---|---|---|",
        ]
        for op, v in list(ops.items())[:10]:
            lines.append(f"| {op} | {_ms(v)} | {100 * v['share']:.0f} % | {v['nodes']} |")
    agreement = [
        (r["name"], k, ref["pose_diff_median"])
        for r in report["models"]
        for k, ref in (r.get("reference") or {}).items()
    ]
    if agreement:
        lines += ["", "Pose agreement, graph vs numpy-FFT reference (median |Δ| over the reference steps):", ""]
        lines += [
            f"- {name}, {k.replace('_', ' ')}: x {d['x_m']:.3f} m, y {d['y_m']:.3f} m, "
            f"yaw {math.degrees(d['yaw_rad']):.3f}°"
            for name, k, d in agreement
        ]
    with_files = [r for r in report["models"] if (r.get("files") or {}).get("pipelined")]
    if with_files:
        lines += [
            "",
            f"End to end on files: {st.get('file_sweeps')} Oxford-layout sweep files read back from disk "
            "through `radar_odom.iter_estimates` (PNG decode + parse + polar→Cartesian on a worker "
            "thread while the graph runs, and the same serially). *Ratio* = wall per sweep / "
            "max(median read, median step); 1.0 is perfect overlap.",
            "",
            "| model | " + " | ".join(head for head, _ in FILE_COLUMNS) + " |",
            "|---|" + "---:|" * len(FILE_COLUMNS),
        ]
        for r in with_files:
            p, s = r["files"]["pipelined"], r["files"].get("serial") or {}
            lines.append(
                f"| {r['name']} | {p['sweeps_per_s']:.1f} | {1e3 * p['wall_per_sweep_s']:.1f} "
                f"| {1e3 * p['load_median_s']:.1f} | {1e3 * p['step_median_s']:.1f} | {p['ratio']:.2f} "
                f"| {s.get('sweeps_per_s', float('nan')):.1f} | {s.get('ratio', float('nan')):.2f} |"
            )
    rs = report.get("rss_stream")
    if rs:
        lines += [
            "",
            f"Memory: {rs['steps']} steps of {rs['model']} through `RadarOdometer` in a fresh process: "
            f"peak RSS {rs['peak_mb']:.0f} MiB; RSS {rs['growth_mb']:+.1f} MiB from step "
            f"{rs['growth_from_step']} to the end (sampled every {rs.get('every', '?')} steps).",
        ]
    lines += ["", "Columns of the latency table:", "", *legend(LATENCY_COLUMNS)]
    if with_files:
        lines += ["", "Columns of the end-to-end table (its stream is timed separately from the steps above, so "
                  "its step median and the latency table's step can differ with the machine's load):", "",
                  *legend(FILE_COLUMNS)]
    untrained = [r["name"] for r in report["models"] if r.get("untrained")]
    if untrained:
        lines += ["", f"Untrained models (exported on the fly, timing only): {', '.join(untrained)}."]
    return "\n".join(lines) + "\n"
