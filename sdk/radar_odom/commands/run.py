"""``radar-odom run SEQ [--model M|NAME] [-o OUTDIR]``: odometry over a recorded sequence."""
from __future__ import annotations

from . import print_warnings, threads_arg

HELP = ("odometry over a recording (Oxford layout, Boreas, MulRan, RADIATE, or a ROS 1/ROS 2 bag); writes "
        "trajectories, estimates and a plot")
EXIT_OK, EXIT_ERROR, EXIT_SKIPPED = 0, 1, 3
EPILOG = (
    "exit status: 0 every sweep was used; 3 the run finished but some sweeps were skipped "
    "(--on-error skip; listed on stderr and in skipped.csv); 1 an error stopped the run "
    "(one line on stderr); 130 Ctrl-C, 143 SIGTERM: the outputs so far are written, marked partial "
    "(partial.txt), and one line says at which sweep."
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help=HELP,
        description=HELP + ". Prints the KITTI odometry metric when the recording has ground truth "
                           "(Oxford radar odometry, Boreas/MulRan poses, RADIATE GNSS/INS aligned in time "
                           "and heading), and then also writes it as ground_truth.tum / ground_truth.kitti "
                           "beside the estimate (for evo_ape / evo_rpe). Gaps in the recording are crossed "
                           "and reported.",
        epilog=EPILOG,
    )
    p.add_argument("sequence",
                   help="recording folder (Oxford or Boreas SEQ/radar/*.png, MulRan SEQ/polar/*.png, RADIATE "
                        "SEQ/Navtech_Polar/*.png), or a ROS bag: a ROS 1 .bag, a ROS 2 bag folder or an .mcap "
                        "file (needs the ros extra: pip install \"radar-odom[ros]\")")
    p.add_argument("-m", "--model", default=None,
                   help="exported .onnx file, or the name of a shipped model (radar_odom.pretrained_names()); "
                        "default: cart-0.4 if shipped, else the first shipped model")
    p.add_argument("-o", "--output", default=None, help="output folder (default: ./run-<SEQ name>)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier run's outputs in the output folder (without it, a folder that holds "
                        "them is refused)")
    p.add_argument("--threads", type=threads_arg, default=None, help="onnxruntime threads (default: physical cores)")
    bags = register_recording_options(p)
    bags.add_argument("--bag-out", default=None, metavar="PATH",
                      help="also write the odometry as a ROS 2 bag (MCAP) folder: nav_msgs/Odometry on "
                           "/radar_odom/odometry (3x3 covariance in the x, y, yaw cells of the 6x6) and TF odom -> "
                           "base_link on /tf, stamped with the sweeps' header stamps")
    p.set_defaults(func=run, interrupted=interrupted)


def interrupted(args, exc) -> str:
    """What `radar-odom run` adds to its interrupted line (commands/interrupts.py): the outputs so far are written
    and marked partial by `run_sequence` (its `RunInterrupted` says where); an interrupt before the odometry
    leaves nothing (a new output folder is removed again)."""
    from ..errors import RunInterrupted

    if isinstance(exc, RunInterrupted):
        return "the same command with --overwrite runs the whole recording again"
    return "nothing written: the odometry had not begun"


def register_recording_options(p):
    """The options that say how one recording is processed (everything but where it and its outputs are):
    `radar-odom run`'s, and the per-recording options of `radar-odom fleet` (`sequence_options`). Returns
    the group of the ROS bag options."""
    import argparse

    from ..odometry.odometer import DESKEW_DEFAULT

    p.add_argument("--plain", action="store_true",
                   help="plain matching, the reference every runtime stage is judged against (docs/scorecard.md): "
                        "stamps as recorded, consecutive matches, the constant-velocity prediction only to place "
                        "the search window; no motion-prior fusion or gate, no gap crossing, no re-timing "
                        "(implies --keep-stamps and --no-motion-prior)")
    p.add_argument("--keep-stamps", action="store_true",
                   help="keep the sweep stamps as recorded (RADIATE, bags): no time base fitted on the sensor's "
                        "period, late host stamps not put back (repair_stamps=False)")
    p.add_argument("--max-gap-s", type=float, default=None,
                   help="stop the run with an error at a larger time (s) between consecutive sweeps (default: "
                        "none; every gap is crossed, its estimate flagged 'gap' and listed at the end)")
    p.add_argument("--deskew", action=argparse.BooleanOptionalAction, default=None,
                   help="motion-compensate each sweep with the velocity so far before matching (default: "
                        f"{'on' if DESKEW_DEFAULT else 'off'}, as measured on real drives; see README)")
    p.add_argument("--centre-yaw", action=argparse.BooleanOptionalAction, default=None,
                   help="draw each sweep turned by the yaw the motion predicts, so the matcher's pull toward "
                        "the pixel grid goes toward the prediction instead of 'no rotation' (default: off: it "
                        "reads simulated bends more fully but measured worse on the real drive; "
                        "docs/yaw-precision.md)")
    p.add_argument("--gt-time-offset", default="auto", metavar="auto|SECONDS",
                   help="GNSS/INS reference (RADIATE): its clock minus the radar's, in s (the reference for "
                        "radar time t is the sample at t + offset); 'auto' (default) estimates it by aligning "
                        "the odometry's yaw rate and speed with the reference, prints it with its cost and "
                        "next-best ratio, and leaves the reference unused where that is ambiguous")
    p.add_argument("--gt-heading-offset-deg", default="auto", metavar="auto|DEGREES",
                   help="GNSS/INS reference: the INS heading minus the vehicle's direction of travel, degrees "
                        "counter-clockwise, one value for the drive, within ±360 (a ROS bag has no reference: "
                        "ignored, and said); 'auto' (default) follows it in time (a ±5 s running median of the "
                        "heading's offset from the GNSS track over moving samples: the INS re-aligns while driving) "
                        "and prints its range")
    p.add_argument("--on-error", choices=("skip", "stop"), default="skip",
                   help="a sweep that cannot be read (corrupt file, garbage timestamps): 'skip' reports it, "
                        "bridges the trajectory across it (flagged degenerate) and exits with status 3; "
                        "'stop' writes the outputs so far and exits with status 1 (default: skip)")
    p.add_argument("--no-pipeline", action="store_true",
                   help="decode each sweep on the main thread when its turn comes, instead of reading the next "
                        "ones ahead on a worker thread while the graph runs (same results; to compare the pace)")
    p.add_argument("--no-plot", action="store_true", help="do not draw trajectory.png (no matplotlib needed)")
    p.add_argument("--no-motion-prior", action="store_true",
                   help="report the raw matches: no fusion with the constant-velocity motion prior "
                        "(on by default; see radar_odom.odometry.motion_prior)")
    return _register_bag_options(p)


def _register_bag_options(p):
    from ..ros.msgs import NAVTECH_SWEEP_PERIOD_S, STAMP_POSITIONS
    from ..scan import OXFORD_ENCODER_SIZE, OXFORD_RANGE_RESOLUTION_M

    g = p.add_argument_group(
        "ROS bags", "sensor_msgs/Image (mono8/mono16) or PNG CompressedImage polar sweeps, one row per azimuth, or "
                    "the Navtech driver's navtech_msgs/msg/RadarBScanMsg (its own azimuth times and encoder angles)")
    g.add_argument("--topic", default=None,
                   help="the radar topic, e.g. /Navtech/Polar (default: the bag's only radar topic; a wrong one "
                        "lists the topics there are)")
    g.add_argument("--range-resolution-m", type=float, default=None,
                   help=f"metres per range bin (column) (default {OXFORD_RANGE_RESOLUTION_M}, Oxford; MulRan 0.0595)")
    g.add_argument("--range-offset-m", type=float, default=None, help="range of column 0, m (default 0)")
    g.add_argument("--sweep-period-s", type=float, default=None,
                   help=f"time of one turn; an Image's azimuth times are spread evenly over it "
                        f"(default {NAVTECH_SWEEP_PERIOD_S})")
    g.add_argument("--stamp", choices=STAMP_POSITIONS, default=None,
                   help="where in the sweep an Image's header stamp lies (default first: the first azimuth, as "
                        "Oxford's file names)")
    g.add_argument("--azimuth-offset-rad", type=float, default=None,
                   help="angle of an Image's row 0, rad (default 0)")
    g.add_argument("--encoder-size", type=int, default=None,
                   help=f"encoder ticks per turn of a B-scan's encoder_values (default {OXFORD_ENCODER_SIZE})")
    return g


BAG_OPTIONS = ("range_resolution_m", "range_offset_m", "sweep_period_s", "stamp", "azimuth_offset_rad",
               "encoder_size")


def run(args) -> int:
    import sys
    import warnings
    from pathlib import Path

    import numpy as np

    from ..errors import GroundTruthWarning, OutputError, RadarOdomError
    from ..evaluation.report import format_metrics
    from ..io.bag import is_bag
    from ..model_zoo import default_model_name, resolve_model
    from ..odometry.gaps import GAP, NEW_SEGMENT, NEW_SEGMENT_GAP_S
    from ..odometry.pipeline import DEFAULT_PREFETCH
    from ..runs.run_sequence import earlier_outputs, run_sequence

    model_spec = args.model or default_model_name()
    model = resolve_model(model_spec)
    out = Path(args.output) if args.output else Path(f"run-{Path(args.sequence).resolve().name}")
    earlier = earlier_outputs(out)
    if earlier and not args.overwrite:
        raise OutputError(f"{out} holds an earlier run's outputs ({', '.join(earlier)}); pass --overwrite to replace "
                          "them, or -o to write elsewhere")
    # the GNSS/INS options are checked before the recording is read (minutes for a long one)
    options = sequence_options(args)
    time_offset_s, heading_offset_deg = options["gt_time_offset"], options["gt_heading_offset_deg"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", GroundTruthWarning)
        try:
            result = run_sequence(args.sequence, model, out, threads=args.threads, bag_out=args.bag_out, **options)
        except RadarOdomError:
            _print_warnings(caught, sys.stderr)
            raise
        except OSError as exc:  # a disk full, a folder made read-only during the run, ...
            _print_warnings(caught, sys.stderr)
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            raise OutputError(f"{where}{exc.strerror or exc}") from None
    _print_warnings(caught, sys.stderr)
    given = [flag for flag, value in (("--gt-time-offset", time_offset_s), ("--gt-heading-offset-deg",
                                                                           heading_offset_deg)) if value is not None]
    if given and is_bag(args.sequence):  # said, not silently dropped
        print(f"radar-odom run: warning: {' and '.join(given)} ignored: a ROS bag carries no GNSS/INS reference "
              "to align (they apply to RADIATE's GPS_IMU_Twist/)", file=sys.stderr)
    gated = sum(e.gated for e in result.estimates)
    dominated = sum(e.prior_dominated for e in result.estimates)
    prior = ("plain matching" if getattr(args, "plain", False) else
             "motion prior off" if args.no_motion_prior else f"{gated} gated, {dominated} prior-dominated")
    print(f"model: {model_spec}" + ("" if str(model) == str(model_spec) else f" ({model})"))
    print(f"{len(result.timestamps_us)} sweeps, {len(result.estimates)} estimates "
          f"({result.num_degenerate} degenerate; {prior}), {1e3 * result.seconds_per_step:.1f} ms per sweep")
    if result.reference_note:
        print(result.reference_note)
    text = format_metrics(result.metrics, result.step_errors)
    if not text and result.reference_note.startswith("reference: GNSS/INS present but not used"):
        text = "no metrics: the GNSS/INS reference is not used (see above)"
    print(text if text else "no ground truth in this recording: no metrics")
    gaps = [(i, e) for i, e in enumerate(result.estimates) if GAP in e.flags]
    if gaps:
        dts = np.diff(result.timestamps_us) * 1e-6
        listed = ", ".join(f"sweep {i + 1} ({dts[i]:.2f} s)" for i, _ in gaps[:8])
        more = f" and {len(gaps) - 8} more" if len(gaps) > 8 else ""
        print(f"crossed {len(gaps)} gap(s) (interval > 1.5 nominal periods; flagged 'gap' in estimates.csv): "
              f"{listed}{more}")
    jumps = [i for i, e in enumerate(result.estimates) if NEW_SEGMENT in e.flags]
    if jumps:
        dts = np.diff(result.timestamps_us) * 1e-6
        print(f"started {len(jumps)} new segment(s) after stamp jumps beyond {NEW_SEGMENT_GAP_S:g} s (the motion over "
              "them is unknown: each new segment continues from the last pose; flagged 'new_segment'): "
              + ", ".join(f"sweep {i + 1} ({dts[i]:.1f} s)" for i in jumps[:8]))
    for kind, path in result.files.items():
        print(f"{kind}: {path}")
    for problem in result.problems:  # stages after the odometry that failed; the outputs above are written
        print(f"radar-odom run: warning: {problem}", file=sys.stderr)
    if result.throughput is not None:
        mode = "no pipeline" if args.no_pipeline else f"pipelined, {DEFAULT_PREFETCH} sweeps ahead"
        print(f"pace ({mode}): {result.throughput.format()}")
    for s in result.skipped:
        print(f"radar-odom run: skipped sweep {s['index']} ({s['reason']}): {s['message']}", file=sys.stderr)
    if result.skipped:
        print(f"radar-odom run: {len(result.skipped)} of {len(result.timestamps_us)} sweeps skipped "
              f"(bridged, flagged degenerate); exit status {EXIT_SKIPPED}", file=sys.stderr)
        return EXIT_SKIPPED
    return EXIT_OK


def sequence_options(args) -> dict:
    """`run_sequence`'s keyword arguments for the options of `register_recording_options` in ``args``, but
    ``threads`` (`run`'s own option: the pace, not the outputs): what `run` passes, and what `radar-odom fleet`
    passes for each recording, so that both write the same outputs. `ConfigError` for a malformed GNSS/INS offset."""
    from ..odometry.pipeline import DEFAULT_PREFETCH

    return dict(max_gap_s=args.max_gap_s, plot=not args.no_plot, motion_prior=not args.no_motion_prior,
                plain=bool(getattr(args, "plain", False)),
                on_error=args.on_error, prefetch=0 if args.no_pipeline else DEFAULT_PREFETCH,
                deskew=args.deskew, centre_yaw=args.centre_yaw,
                gt_time_offset=_offset(args.gt_time_offset, "--gt-time-offset"),
                gt_heading_offset_deg=_offset(args.gt_heading_offset_deg, "--gt-heading-offset-deg", limit=360.0),
                topic=args.topic,
                bag_geometry={k: getattr(args, k) for k in BAG_OPTIONS if getattr(args, k, None) is not None},
                repair_stamps=not args.keep_stamps)


def _offset(text: str, flag: str, limit: float | None = None):
    """'auto' → None (estimate it), else the number; a clear error for anything else (beyond ±``limit`` too)."""
    import math

    from ..errors import ConfigError

    if str(text).strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"{flag} takes 'auto' or a number, got {text!r}") from None
    if not math.isfinite(value):
        raise ConfigError(f"{flag} must be finite, got {text!r}")
    if limit is not None and abs(value) > limit:
        raise ConfigError(f"{flag} {text}: beyond ±{limit:g}; give an angle within a turn, or 'auto'")
    return value


def _print_warnings(caught, stream) -> None:
    print_warnings("run", caught, stream)
