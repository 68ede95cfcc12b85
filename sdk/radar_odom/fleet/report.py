"""The fleet report: one row per recording (``OUT/fleet.csv``) and a summary page with plots (``OUT/fleet.md``).

Every figure of a row comes from the `RunResult` that `radar-odom run` prints its own lines from (the same
counts, the same metrics, the same GNSS/INS offsets), written at full precision. Lengths and speeds are the
estimated trajectory's (every recording has one; a reference does not always exist).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

COLUMNS = (
    "recording", "status", "reason", "attempts", "sweeps", "estimates", "duration_s", "length_m",
    "mean_speed_m_s", "sweeps_per_s", "seconds", "translation_percent", "rotation_deg_per_m", "step_translation_m",
    "step_rotation_deg", "degenerate", "gaps", "gated", "prior_dominated", "skipped_sweeps", "clock_offset_s",
    "heading_offset_deg", "warnings", "node", "path",
)
DONE, KEPT, FAILED = "done", "kept", "failed"  # this run; an earlier run's outputs, valid; failed twice
WORST_SHOWN = 5


def result_row(name: str, recording, result, seconds: float | str = "") -> dict:
    """The report row of a finished `run_sequence` ``result`` (`COLUMNS`; empty where unknown); ``seconds``:
    the recording's wall time in its worker, reading to manifest (sweeps/s is the odometry loop's alone)."""
    from ..evaluation.metrics import path_lengths_m
    from ..odometry.gaps import GAP

    ts = np.asarray(result.timestamps_us, dtype=np.int64)
    duration_s = float(ts[-1] - ts[0]) * 1e-6 if len(ts) >= 2 else 0.0
    length_m = float(path_lengths_m(np.asarray(result.poses))[-1]) if len(ts) else 0.0
    metrics, steps, ref = result.metrics or {}, result.step_errors or {}, result.reference or {}
    est = result.estimates
    return {
        "recording": name, "status": DONE, "reason": "", "attempts": 1,
        "sweeps": len(ts), "estimates": len(est), "duration_s": duration_s, "length_m": length_m,
        "mean_speed_m_s": length_m / duration_s if duration_s > 0 else "",
        "sweeps_per_s": result.throughput.sweeps_per_s if result.throughput is not None else "", "seconds": seconds,
        "translation_percent": metrics.get("translation_percent", ""),
        "rotation_deg_per_m": metrics.get("rotation_deg_per_m", ""),
        "step_translation_m": steps.get("mean_translation_m", ""),
        "step_rotation_deg": steps.get("mean_rotation_deg", ""),
        "degenerate": result.num_degenerate, "gaps": sum(GAP in e.flags for e in est),
        "gated": sum(e.gated for e in est), "prior_dominated": sum(e.prior_dominated for e in est),
        "skipped_sweeps": len(result.skipped),
        "clock_offset_s": ref.get("clock_offset_s", ""), "heading_offset_deg": ref.get("heading_offset_deg", ""),
        "warnings": "", "node": "", "path": str(recording),
    }


def check_reports(out_dir) -> None:
    """Before any work: `OutputError` where ``out_dir`` holds a report name (`manifest.REPORT_FILES`: a file,
    a folder) that fleet did not write: not claimed by its `manifest.REPORTS_MANIFEST` (`claim_reports`), nor
    an earlier fleet's ``fleet.csv`` (written before that manifest: its header says so)."""
    from ..errors import OutputError
    from ..outputs import foreign_files
    from .manifest import REPORT_FILES, REPORTS_MANIFEST

    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        return
    foreign = foreign_files(out_dir, REPORTS_MANIFEST, names=REPORT_FILES)
    if foreign and not (out_dir / REPORTS_MANIFEST).exists() and _earlier_fleet_csv(out_dir / "fleet.csv"):
        return
    if foreign:
        raise OutputError(f"{out_dir}: holds {', '.join(foreign)}, which radar-odom fleet did not write (the report "
                          "takes those names); nothing was touched: give -o another folder, or move them")


def _earlier_fleet_csv(path: Path) -> bool:
    try:
        with open(path, newline="") as f:
            return f.readline().startswith(",".join(COLUMNS[:3]) + ",")
    except (OSError, UnicodeDecodeError):
        return False


def claim_reports(out_dir) -> Path:
    """``out_dir``'s `manifest.REPORTS_MANIFEST`, naming the report files as fleet's: written before them, so a
    run stopped half-way through writing them still finds them its own."""
    from ..outputs import write_folder_manifest
    from .manifest import REPORT_FILES, REPORTS_MANIFEST

    return write_folder_manifest(out_dir, REPORTS_MANIFEST, "fleet", files=REPORT_FILES)


def failed_row(name: str, recording, reason: str, attempts: int) -> dict:
    row = dict.fromkeys(COLUMNS, "")
    row.update(recording=name, status=FAILED, reason=reason, attempts=attempts, path=str(recording))
    return row


def _cell(value) -> str:
    """Full precision (``repr`` of a float: it reads back to the same number), '' for unknown."""
    if isinstance(value, (float, np.floating)):
        return "" if not math.isfinite(value) else repr(float(value))
    return str(value)


def write_csv(path, rows: list[dict]) -> Path:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for row in rows:
            w.writerow([_cell(row.get(c, "")) for c in COLUMNS])
    tmp.replace(path)
    return path


def read_csv(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def error_of(row: dict) -> tuple[str, float] | None:
    """The error a row is ranked by: KITTI translation % where the drive has it, else the mean per-step
    translation error (m); None without a reference."""
    for key in ("translation_percent", "step_translation_m"):
        value = row.get(key, "")
        if value not in ("", None):
            return key, float(value)
    return None


def write_summary(out_dir, rows: list[dict], command: str = "") -> Path:
    """``out_dir/fleet.md``: totals, the failures with their reasons, the worst drives linked to their own
    ``trajectory.png``, and ``fleet-error.png`` (error against mean speed and against length) when at least
    one recording has a reference and matplotlib is installed."""
    out_dir = Path(out_dir)
    ok = [r for r in rows if r["status"] != FAILED]
    failed = [r for r in rows if r["status"] == FAILED]
    lines = ["# Fleet report", ""]
    if command:
        lines += [f"`{command}`", ""]
    sweeps = sum(int(r["sweeps"]) for r in ok)
    hours = sum(float(r["duration_s"]) for r in ok) / 3600
    km = sum(float(r["length_m"]) for r in ok) / 1000
    lines += [f"{len(rows)} recordings: {sum(r['status'] == DONE for r in rows)} done now, "
              f"{sum(r['status'] == KEPT for r in rows)} kept from an earlier run, {len(failed)} failed; "
              f"{sweeps} sweeps, {hours:.2f} h, {km:.2f} km (estimated). One row each in fleet.csv.", ""]
    if failed:
        lines += ["## Failed", ""] + [f"- `{r['recording']}` ({r['path']}): {r['reason']}" for r in failed] + [""]
    # KITTI % first, then the per-step metres of drives too short for it: the two are not one scale
    ranked = sorted(((e[1], e[0], r) for r in ok if (e := error_of(r)) is not None),
                    key=lambda t: (t[1] != "translation_percent", -t[0]))
    if ranked:
        plot = _plot_errors(out_dir / "fleet-error.png", ranked)
        # one table per unit: KITTI % (drives long enough for its segments), then per-step metres (shorter ones)
        for key, title, unit in (("translation_percent", "Worst drives", "KITTI translation %"),
                                 ("step_translation_m", "Worst short drives (too short for KITTI segments)",
                                  "mean step error m")):
            worst = [(value, r) for value, k, r in ranked if k == key][:WORST_SHOWN]
            if not worst:
                continue
            lines += [f"## {title}", "", f"| recording | {unit} | length m | mean speed m/s | plot |",
                      "|---|---|---|---|---|"]
            for value, r in worst:
                own = out_dir / r["recording"] / "trajectory.png"
                pic = f"[trajectory]({r['recording']}/trajectory.png)" if own.is_file() else ""
                lines.append(f"| `{r['recording']}` | {value:.3f} | {float(r['length_m']):.1f} | "
                             f"{_num(r['mean_speed_m_s'], '.2f')} | {pic} |")
            lines.append("")
        if plot is not None:
            lines += ["![error against speed and distance](fleet-error.png)", ""]
    else:
        lines += ["No recording has a reference: no errors to rank.", ""]
    path = out_dir / "fleet.md"
    path.write_text("\n".join(lines))
    return path


def _num(value, spec: str) -> str:
    return "" if value in ("", None) else format(float(value), spec)


def _plot_errors(path, ranked) -> Path | None:
    """Error against mean speed and against length, one dot per recording (KITTI % and per-step metres on
    their own axes: they are not one quantity)."""
    try:
        import matplotlib
    except ImportError:
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = sorted({key for _, key, _ in ranked})
    fig, axes = plt.subplots(len(kinds), 2, figsize=(10, 4 * len(kinds)), squeeze=False)
    for k, kind in enumerate(kinds):
        pts = [(float(r["mean_speed_m_s"] or "nan"), float(r["length_m"]), v) for v, key, r in ranked if key == kind]
        speed, length, err = (np.array(c) for c in zip(*pts))
        label = "KITTI translation %" if kind == "translation_percent" else "mean per-step translation error, m"
        for ax, x, xlabel in ((axes[k, 0], speed, "mean speed, m/s"), (axes[k, 1], length, "length, m")):
            ax.scatter(x, err, s=18)
            ax.set_xlabel(xlabel)
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)
