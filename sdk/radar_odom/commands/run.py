"""``radar-odom run SEQ [--model M|NAME] [-o OUTDIR]``: odometry over a recorded sequence."""
from __future__ import annotations

HELP = "odometry over a recording (Oxford layout, Boreas, MulRan); writes trajectories, estimates and a plot"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help=HELP,
        description=HELP + ". Prints the KITTI odometry metric when the recording has ground truth."
    )
    p.add_argument("sequence", help="recording folder (e.g. SEQ with SEQ/radar/*.png)")
    p.add_argument("-m", "--model", default=None,
                   help="exported .onnx file, or the name of a shipped model (radar_odom.pretrained_names()); "
                        "default: cart-0.4 if shipped, else the first shipped model")
    p.add_argument("-o", "--output", default=None, help="output folder (default: ./run-<SEQ name>)")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime threads (default: physical cores)")
    p.add_argument("--max-gap-s", type=float, default=1.0,
                   help="largest time (s) between consecutive sweeps before the run stops with an error (default: 1.0)")
    p.add_argument("--no-plot", action="store_true", help="do not draw trajectory.png (no matplotlib needed)")
    p.add_argument("--no-motion-prior", action="store_true",
                   help="report the raw matches: no fusion with the constant-velocity motion prior "
                        "(on by default; see radar_odom.motion_prior)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..pretrained import default_model_name, resolve_model
    from ..run import format_metrics, run_sequence

    model = resolve_model(args.model or default_model_name())
    out = Path(args.output) if args.output else Path(f"run-{Path(args.sequence).resolve().name}")
    result = run_sequence(args.sequence, model, out, threads=args.threads, max_gap_s=args.max_gap_s,
                          plot=not args.no_plot, motion_prior=not args.no_motion_prior)
    gated = sum(e.gated for e in result.estimates)
    dominated = sum(e.prior_dominated for e in result.estimates)
    prior = "motion prior off" if args.no_motion_prior else f"{gated} gated, {dominated} prior-dominated"
    print(f"{len(result.timestamps_us)} sweeps, {len(result.estimates)} estimates "
          f"({result.num_degenerate} degenerate; {prior}), {1e3 * result.seconds_per_step:.1f} ms per sweep")
    text = format_metrics(result.metrics, result.step_errors)
    print(text if text else "no ground truth in this recording: no metrics")
    for kind, path in result.files.items():
        print(f"{kind}: {path}")
    return 0
