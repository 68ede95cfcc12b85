"""``radar-odom demo``: simulate a short drive, run a shipped model on it, print metrics, save a plot."""
from __future__ import annotations

from . import threads_arg

HELP = "simulate a short drive (held-out seed) and run a shipped model on it end to end"
#: demo's manifest in its folder: the files it wrote, the only ones a later demo replaces
MANIFEST = ".radar-odom-demo.json"


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
        help="folder for the drive, trajectories and plot (default: ./radar-odom-demo): a new folder, or an "
             "earlier demo's (its files are replaced; a folder holding anything else is refused)",
    )
    p.add_argument("--threads", type=threads_arg, default=None, help="onnxruntime threads (default: physical cores)")
    p.set_defaults(func=run, interrupted=lambda args, exc: f"{args.output} holds this demo's files so far; "
                                                           "`radar-odom demo` again replaces them")


def run(args) -> int:
    from ..model_zoo import default_model_name, resolve_model
    from ..outputs import check_output_folder, files_below, remove_own_outputs, write_folder_manifest
    from ..runs.run_sequence import new_folder_removed_on_error

    # before any work, in one line: -o a file, or a folder holding anything but an earlier demo's own files
    own = check_output_folder(args.output, MANIFEST, "demo")
    resolve_model(args.model or default_model_name())  # a model that is not there: said before anything goes
    # a failed demo leaves no empty folder behind
    with new_folder_removed_on_error(args.output) as out:
        if own:
            remove_own_outputs(out, MANIFEST)  # the earlier demo's files: its drive may be another seed's
        try:
            _demo(args, out)
        finally:  # what is in the folder now is this demo's (it held nothing else): a later demo may replace it
            if [f for f in files_below(out) if f != MANIFEST]:
                write_folder_manifest(out, MANIFEST, "demo")
            elif own:
                (out / MANIFEST).unlink(missing_ok=True)
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
