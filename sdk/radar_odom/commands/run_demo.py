"""The embedded default: simulate a short drive, run a shipped model on it, report, plot.

The drive is written in the Oxford layout and read back through `read_sequence`, so the demo
exercises exactly the path a real recording takes. Its seed (`DEFAULT_SEED`) is held out: no
pretrained model was trained on it.
"""
from __future__ import annotations

from pathlib import Path

from ..model_zoo import default_model_name

DEFAULT_FRAMES = 120  # 30 s at 4 Hz: long enough for 100 m KITTI segments at urban speeds
DEFAULT_SEED = 9005  # held out (training 1000-2999); a drive with a 84° turn and a stop


def run_demo(frames: int = DEFAULT_FRAMES, model: str | None = None, seed: int = DEFAULT_SEED,
             scenario: str = "urban", out_dir="radar-odom-demo", threads=None, echo=print):
    """Simulate ``frames`` sweeps into ``out_dir/drive``, run the model, write outputs in ``out_dir``.

    Returns the `RunResult`.
    """
    import time

    from ..evaluation.report import format_metrics
    from ..model_zoo import resolve_model
    from ..runs.run_sequence import run_sequence
    from ..sim import write_drive

    model_path = resolve_model(model or default_model_name())
    out_dir = Path(out_dir)
    drive = out_dir / "drive"
    t0 = time.perf_counter()
    write_drive(drive, seed=seed, frames=frames, scenario=scenario)
    t_sim = time.perf_counter() - t0
    echo(f"simulated {frames} sweeps ({scenario}, seed {seed}) in {t_sim:.1f} s -> {drive}")
    result = run_sequence(drive, model_path, out_dir, threads=threads,
                          title=f"radar-odom demo: {Path(model_path).stem} on simulated {scenario} drive (seed {seed})")
    echo(f"model {Path(model_path).name}: {len(result.estimates)} estimates "
         f"({result.num_degenerate} degenerate), {1e3 * result.seconds_per_step:.1f} ms per sweep "
         f"(wall time: decode + polar->Cartesian on a worker thread, the graph on this one)")
    if result.throughput is not None:
        echo(f"pace: {result.throughput.format()}")
    echo(format_metrics(result.metrics, result.step_errors))
    for kind, path in result.files.items():
        echo(f"{kind}: {path}")
    return result
