"""``radar-odom demo``: simulate a short drive, run a shipped model on it, print metrics, save a plot."""
from __future__ import annotations

from . import threads_arg

HELP = "simulate a short drive (held-out seed) and run a shipped model on it end to end"


def register(subparsers) -> None:
    from .run_demo import DEFAULT_FRAMES, DEFAULT_SEED

    p = subparsers.add_parser("demo", help=HELP, description=HELP + "; prints metrics and saves a plot.")
    p.add_argument(
        "--frames",
        type=int,
        default=DEFAULT_FRAMES,
        help=f"sweeps to simulate, 4 per second (default: {DEFAULT_FRAMES})",
    )
    p.add_argument(
        "--model",
        default=None,
        help="shipped model name or .onnx path (default: cart-0.4 if shipped, else the first shipped)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        help=f"simulator seed (default {DEFAULT_SEED}: never used in training)",
    )
    p.add_argument(
        "--scenario", default="urban", choices=("urban", "heavy_traffic", "open", "highway"),
        help="simulator scenario (default: urban)"
    )
    p.add_argument(
        "-o",
        "--output",
        default="radar-odom-demo",
        help="folder for the drive, trajectories and plot (default: ./radar-odom-demo)",
    )
    p.add_argument("--threads", type=threads_arg, default=None, help="onnxruntime threads (default: physical cores)")
    p.set_defaults(func=run)


def run(args) -> int:
    from .run_sequence import new_folder_removed_on_error

    # OutputError (one line) when -o names a file; a failed demo leaves no empty folder behind
    with new_folder_removed_on_error(args.output) as out:
        _demo(args, out)
    return 0


def _demo(args, out) -> None:
    from ..errors import OutputError
    from .run_demo import run_demo

    try:
        run_demo(
            frames=args.frames,
            model=args.model,
            seed=args.seed,
            scenario=args.scenario,
            out_dir=out,
            threads=args.threads,
            echo=print,
        )
    except OSError as exc:  # a disk full, a folder made read-only meanwhile, ...
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        raise OutputError(f"{where}{exc.strerror or exc}") from None
