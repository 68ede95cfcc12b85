"""``radar-odom profile``: CPU latency per grid resolution, per stage and per operator class."""
from __future__ import annotations

from . import help_formatter, threads_arg

HELP = "CPU latency of the shipped models: per stage, per operator class, peak memory, numpy-FFT reference"


def register(subparsers) -> None:
    import argparse

    from ..latency.columns import help_text
    from ..runtimes import RUNTIMES

    class Formatter(help_formatter(), argparse.RawDescriptionHelpFormatter):
        pass

    p = subparsers.add_parser(
        "profile", help=HELP,
        description=(
            HELP + ".\n\nStreams simulated sweeps (Oxford-layout PNGs) through each model and times PNG decode, "
            "sweep parsing,\npolar→Cartesian and the graph (median, p90, p99 after a warm-up), groups the graph's "
            "time by operator\nclass with onnxruntime's profiler, times the same search in numpy (pocketfft) on the "
            "same masked images,\nstreams sweep files end to end, and runs a RadarOdometer stream in a fresh process "
            "for its memory.\nBy default the shipped models (radar_odom.pretrained_names()); every phase is announced, "
            "and a\nline printed at least every 10 s. Writes OUT/profile.json and OUT/profile.md and nothing "
            "else,\nunless --keep-traces (onnxruntime's JSON traces) or an untrained export for a profile with no\n"
            "model (--profiles cart-0.2: needs torch; its .onnx is written under OUT/models and named).\n"
            "The defaults took 34 s on an idle 2-core AMD EPYC (2026-12-05)."
        ),
        epilog=help_text(),
        formatter_class=Formatter,
    )
    p.add_argument("--models", nargs="*", default=[], metavar="NAME|PATH",
                   help="shipped model names (radar_odom.pretrained_names()) or exported .onnx files")
    p.add_argument("--profiles", nargs="*", default=None, metavar="PROFILE",
                   help="grid profiles to cover; one without a model in --models uses the shipped model of that "
                        "name, or else an untrained export timed only, e.g. cart-0.2 (needs torch) (default: the "
                        "shipped models)")
    p.add_argument("--search", choices=("fast", "exhaustive"), default="fast",
                   help="rotation search of the untrained exports: coarse-to-fine or every yaw candidate; a "
                        "model given in --models is timed with the search its file names")
    p.add_argument(
        "--threads", type=threads_arg, default=None, help="onnxruntime threads (default: physical cores)%(default).0s"
    )
    p.add_argument("--runtime", choices=RUNTIMES, default="onnxruntime",
                   help="runtime the stream steps run on (radar_odom.runtimes; openvino: its own runtime; "
                        "onnxruntime-openvino: onnxruntime's OpenVINO provider, from the onnxruntime-openvino wheel "
                        "in its own environment or the onnxruntime-ep-openvino plugin on Intel CPUs; the operator "
                        "table and the file throughput stay onnxruntime CPU's and are left out)")
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
        default=200,
        help="steps of a RadarOdometer stream at --rss-profile in a fresh process, sampling RSS (0: none; "
        "benchmarks/soak.py runs the long leak check)",
    )
    p.add_argument(
        "--file-sweeps",
        type=int,
        default=40,
        help="sweep files streamed end to end (decode + parse + step) per model, pipelined and serially, "
        "for sweeps/s (0: none)",
    )
    p.add_argument("--rss-profile", default="cart-0.4", help="profile whose model runs the RSS stream")
    p.add_argument("-o", "--output", default="radar-odom-profile", help="output folder")
    p.add_argument("--keep-traces", action="store_true",
                   help="keep onnxruntime's JSON traces of the --operator-steps in OUT (tens of MB per model)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def default_profile_names() -> list[str]:
    """The shipped models' names: what `radar-odom profile` times without --profiles / --models
    (cart-0.2 has no shipped model: an untrained export of it only on request)."""
    from ..errors import ConfigError
    from ..model_zoo import pretrained_names

    names = pretrained_names()
    if not names:
        raise ConfigError("this installation ships no models: give --models PATH.onnx (or --profiles NAME with "
                          "torch installed, for an untrained export timed only)")
    return names


def run(args) -> int:
    import shlex
    import sys

    from ..latency import run_profile

    if args.profiles is None:
        args.profiles = [] if args.models else default_profile_names()
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
        keep_traces=args.keep_traces,
        runtime=args.runtime,
    )
    return 0
