"""``radar-odom profile``: CPU latency per grid resolution, per stage and per operator class."""
from __future__ import annotations

from . import help_formatter, threads_arg

HELP = "CPU latency per grid resolution: per stage, per operator class, peak memory, numpy-FFT reference"
PROFILE_NAMES = ("cart-0.8", "cart-0.4", "cart-0.2")  # radar_odom.latency.DEFAULT_PROFILES, kept light


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "profile", help=HELP,
        description=(
            HELP + ". Streams simulated sweeps (Oxford-layout PNGs) through each model and times PNG "
            "decode, sweep parsing, polar→Cartesian and the graph (median, p90, p99 after a warm-up), "
            "groups the graph's time by operator class with onnxruntime's profiler, and times the same "
            "search in numpy (pocketfft) on the same masked images. Writes OUT/profile.json and "
            "OUT/profile.md. A profile with no model given and none shipped gets an untrained model exported "
            "on the fly (needs torch, the export extra; weights do not change the time); without torch the "
            "default --profiles are the shipped models' only."
        ),
        formatter_class=help_formatter(),
    )
    p.add_argument("--models", nargs="*", default=[], metavar="NAME|PATH",
                   help="shipped model names (radar_odom.pretrained_names()) or exported .onnx files")
    p.add_argument("--profiles", nargs="*", default=None, metavar="PROFILE",
                   help="grid profiles to cover; one without a model in --models uses the shipped model of that "
                        f"name, or else an untrained export (default: {' '.join(PROFILE_NAMES)}; without torch "
                        "only those with a shipped model)")
    p.add_argument("--search", choices=("fast", "exhaustive"), default="fast",
                   help="rotation search of the untrained exports: coarse-to-fine or every yaw candidate; a "
                        "model given in --models is timed with the search its file names")
    p.add_argument(
        "--threads", type=threads_arg, default=None, help="onnxruntime threads (default: physical cores)%(default).0s"
    )
    p.add_argument("--steps", type=int, default=200, help="timed stream steps per model")
    p.add_argument("--warmup", type=int, default=20, help="untimed steps first")
    p.add_argument(
        "--reference-steps",
        type=int,
        default=30,
        help="steps timed with the numpy-FFT reference (0: none; the exhaustive one is slow)",
    )
    p.add_argument(
        "--operator-steps",
        type=int,
        default=50,
        help="steps traced with onnxruntime's profiler for the operator table (0: none)",
    )
    p.add_argument(
        "--rss-steps",
        type=int,
        default=1000,
        help="steps of a RadarOdometer stream at --rss-profile in a fresh process, sampling RSS (0: none)",
    )
    p.add_argument(
        "--file-sweeps",
        type=int,
        default=100,
        help="sweep files streamed end to end (decode + parse + step) per model, pipelined and serially, "
        "for sweeps/s (0: none)",
    )
    p.add_argument("--rss-profile", default="cart-0.4", help="profile whose model runs the RSS stream")
    p.add_argument("-o", "--output", default="radar-odom-profile", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def default_profile_names(torch_available: bool | None = None, echo=print) -> list[str]:
    """`PROFILE_NAMES`, less those with no shipped model when torch (needed to export an untrained
    one) is not installed; each one left out is named, with what to do."""
    import importlib.util

    from ..model_zoo import pretrained_names

    if torch_available is None:
        torch_available = all(importlib.util.find_spec(m) is not None for m in ("torch", "radar_odom_export"))
    if torch_available:
        return list(PROFILE_NAMES)
    shipped = set(pretrained_names())
    keep = [n for n in PROFILE_NAMES if n in shipped]
    for name in PROFILE_NAMES:
        if name not in shipped:
            echo(f"note: profile {name} left out: no shipped model, and torch is not installed to export an "
                 f"untrained one (install the export extra, or pass --models PATH.onnx --profiles {name})")
    return keep


def run(args) -> int:
    import shlex
    import sys

    from ..latency import run_profile

    if args.profiles is None:
        args.profiles = default_profile_names()
    if 1 <= args.steps < 200:
        print(f"note: --steps {args.steps} is below 200; p99 over so few steps is rough")
    run_profile(
        args.models,
        args.profiles,
        threads=args.threads,
        steps=args.steps,
        warmup=args.warmup,
        reference_steps=args.reference_steps,
        operator_steps=args.operator_steps,
        rss_steps=args.rss_steps,
        file_sweeps=args.file_sweeps,
        rss_profile=args.rss_profile,
        search=args.search,
        out_dir=args.output,
        command="radar-odom " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
        progress_bar=not args.no_progress,
    )
    return 0
