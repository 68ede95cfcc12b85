"""``radar-odom export model.pt [-o model.onnx] [--form stream|pair|sequence|sweep] [--search exhaustive|fast]
[--opset N] [--exporter auto|dynamo|torchscript] [--quantize static [--quantize-real SEQ]]``.

A shipped name (``radar-odom export cart-0.4``) reproduces the shipped model: its search, search
settings and form are read from the shipped ONNX file's metadata (``radar_odom.search``,
``radar_odom.form``) unless ``--search`` / ``--form`` say otherwise. A user's checkpoint is
written as the shipped models are: the fast search, the stream form, and a calibrated covariance
(a checkpoint that `radar-odom calibrate` has not calibrated is calibrated first, in place, with
that command's defaults; ``--no-calibrate`` writes it as it is, with a warning)."""
from __future__ import annotations

from radar_odom.commands import threads_arg
from radar_odom.model_file import DEFAULT_OPSET, MIN_EXPORT_OPSET
from radar_odom.model_zoo import shipped_export  # noqa: F401  (re-exported: its home is radar_odom.model_zoo)
from radar_odom.outputs import check_output_path  # noqa: F401  (re-exported: its home is radar_odom.outputs)

DEFAULT_CALIBRATION_MINUTES = 3.0  # `--calibration-minutes`: an export that calibrates first ends in a known time
HELP = "export a trained checkpoint to one self-contained ONNX graph (sweep in, pose + covariance out)"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help=HELP, description=HELP + ". A checkpoint without a calibrated covariance (straight "
        "from `radar-odom train`) is first calibrated in place as `radar-odom calibrate CHECKPOINT` would "
        "(simulated held-out drives, within --calibration-minutes, with a progress bar and the d² table), so "
        "the file written is what the shipped models are: fast search, stream form, calibrated covariance. Needs "
        "the torch side, radar-odom-export (torch, onnx, onnxscript)."
    )
    p.add_argument("checkpoint", help="checkpoint written by `radar-odom train` (.pt), or the name of a "
                                      "shipped one (cart-0.8, cart-0.4): the weights of the pretrained models")
    p.add_argument("-o", "--output", default=None,
                   help="ONNX file to write (default: the checkpoint's name, or NAME for a shipped one, with the "
                        "search and form appended where they are not its default, e.g. cart-0.4-exhaustive.onnx)")
    p.add_argument("--force", action="store_true", help="overwrite the output file if it exists")
    p.add_argument("--form", choices=("stream", "pair", "sequence", "sweep"), default=None,
                   help="stream: (sweep, previous state) -> (pose, covariance, state), masks each sweep once; "
                        "pair: (previous sweep, sweep) -> (pose, covariance), for evaluation; sequence: T "
                        "consecutive sweeps -> T-1 poses and covariances in one call, for offline batches "
                        "(radar_odom.match_sequence; fast search); sweep: the stream form taking the raw polar "
                        "sweep (power, azimuths, range resolution and offset) and drawing the Cartesian image "
                        "itself, for runtimes outside Python (docs/sweep-form.md). Default: stream")
    p.add_argument("--search", choices=("exhaustive", "fast"), default=None,
                   help="exhaustive: score every yaw candidate (the paper's search); fast: coarse-to-fine yaw "
                        "search, several times faster on a CPU, stream and sequence forms (default: a shipped "
                        "name's own search, read from the shipped model; else fast, as the shipped models, or "
                        "exhaustive for --form pair and for a dual-mode profile). The decoupled search (Fast-MbyM) "
                        "is retired from the CLI: 27 %% less accurate and not fast enough to pay for it "
                        "(docs/latency.md)")
    p.add_argument("--no-calibrate", action="store_true",
                   help="write a checkpoint that was never calibrated as it is: its covariance is then the raw "
                        "softmax moment, not a calibrated 1σ (most estimates come out prior_dominated); warned")
    p.add_argument("--calibration-minutes", type=float, default=DEFAULT_CALIBRATION_MINUTES, metavar="M",
                   help="wall-clock budget of an export that calibrates first, counted from the command's start "
                        "and writing the ONNX file included: the calibration simulates every scenario within its "
                        "first quarter (each drive cut short to fit) and takes as many pairs, spread over every "
                        "drive, as fit in 70 %% of it (at least one batch; the line after the d² table says how "
                        "many of how many), the rest is left for the writing; 0: no budget, every pair "
                        "`radar-odom calibrate` takes "
                        "(default: %(default)s; at most a week)")
    p.add_argument("--calibration-data", nargs="+", default=None, metavar="DIR",
                   help="recordings with ground truth to calibrate an uncalibrated checkpoint on, instead of "
                        "`radar-odom calibrate`'s simulated held-out drives")
    p.add_argument("--threads", type=threads_arg, default=None,
                   help="torch threads for that calibration (default: all cores)")
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET,
                   help=f"ONNX opset to write, {MIN_EXPORT_OPSET} or later; the written file is checked to have it "
                        f"(default: {DEFAULT_OPSET})")
    p.add_argument("--exporter", choices=("auto", "dynamo", "torchscript"), default="auto",
                   help="torch.onnx exporter; auto: dynamo, falling back to TorchScript only if the dynamo "
                        "exporter itself fails (default: auto)")
    p.add_argument("--quantize", choices=("static", "int8"), default=None,
                   help="static: quantise the masker's Conv nodes (static QDQ, int8 weights per channel, uint8 "
                        "activations, percentile ranges calibrated on simulated validation drives, seeds "
                        "2000-2001, plus the sweeps of --quantize-real); the correlation stays float32; int8 is "
                        "an earlier name of static. Verified against the float32 export on held-back simulated "
                        "sweeps (--no-verify skips this too); the scheme and its calibration data are recorded "
                        "in the metadata as radar_odom.quantization (default: float32 throughout)")
    p.add_argument("--quantize-real", action="append", default=[], metavar="SEQ",
                   help="with --quantize: a real recording whose sweeps join the calibration, all but its last "
                        "80 (held out, as calibrate's --real holds them out); repeatable")
    p.add_argument("--quantize-float", default="first,last", metavar="first,last|none",
                   help="with --quantize: which of the masker's Conv nodes stay float32: first, last, both, or "
                        "none (default: %(default)s)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip the onnxruntime-vs-torch check on fresh random sweeps (a difference beyond the "
                        "tolerance fails the export and writes nothing)")
    p.set_defaults(func=run)


def run(args) -> int:
    import time
    from pathlib import Path

    from radar_odom.errors import MissingExtraError, OutputError

    try:
        from radar_odom_export.checkpoint import resolve_checkpoint
        from radar_odom_export.onnx_export import check_search_form, export_checkpoint
    except ImportError as exc:  # torch / onnx missing: say which extra to install
        raise MissingExtraError(getattr(exc, "name", None) or "torch", "export") from exc
    args.started = time.perf_counter()  # a calibration's budget counts from here
    if args.no_calibrate and args.calibration_data:  # issue 51: the data was ignored without a word
        from radar_odom.errors import ConfigError

        raise ConfigError("--no-calibrate and --calibration-data contradict each other: drop --no-calibrate to "
                          "calibrate on that data, or drop --calibration-data to export uncalibrated")
    if args.quantize_real and not args.quantize:
        from radar_odom.errors import ConfigError

        raise ConfigError("--quantize-real calibrates a quantised masker: give --quantize static too, or leave "
                          "it out")
    check_calibration_minutes(args)
    check_opset(args.opset)
    ckpt = resolve_checkpoint(args.checkpoint)
    shipped = None if Path(args.checkpoint).is_file() else shipped_export(ckpt.stem)
    form, settings = args.form, None
    if shipped is not None and args.search in (None, shipped["search"]) and args.form in (None, shipped["form"]):
        # reproduce the shipped model: its search with its settings, its form
        search, form, settings = shipped["search"], shipped["form"], shipped["settings"]
        tag = ""
    elif shipped is not None and args.search in (None, shipped["search"]) and args.form == "sweep":
        # the shipped model's stream graph, with the drawing in front
        search, settings, tag = shipped["search"], shipped["settings"], "-sweep"
    else:
        default = default_search(ckpt, form)
        search = args.search or default
        plain = shipped is None and search == default and form in (None, "stream")
        tag = "" if plain else f"-{search}" + (f"-{form}" if form not in (None, "stream") else "")
    # the default name says the search and form (two exports never share it); a shipped name writes
    # NAME.onnx in the working directory, never into the package
    if args.output:
        out = Path(args.output)
    else:
        stem = Path(args.checkpoint).with_suffix("") if Path(args.checkpoint).is_file() else Path(ckpt.stem)
        out = stem.with_name(f"{stem.name}{tag}.onnx")
    if out.exists() and not args.force:
        raise OutputError(f"{out} exists; pass --force to overwrite it, or -o to write elsewhere")
    check_output_path(out)
    check_search_form(search, form)  # before a calibration of minutes
    check_fast_rotation(ckpt, search)
    calibrate_first(ckpt, search, args)
    common = dict(form=form, opset=args.opset, verify=not args.no_verify, search=search,
                  exporter=args.exporter)
    if settings is not None:
        common["search_settings"] = settings
    if args.quantize and form == "sweep":
        from radar_odom.errors import ConfigError

        raise ConfigError("--quantize writes the stream form only; the sweep form of an int8 graph is not made "
                          "(leave out --quantize, or --form)")
    if args.quantize:
        try:
            from radar_odom_export.quantize import export_quantized
        except ImportError as exc:
            raise MissingExtraError(getattr(exc, "name", None) or "onnxruntime", "export") from exc
        keep = "" if args.quantize_float == "none" else args.quantize_float
        fp32, quant = export_quantized(ckpt, out, quantize=args.quantize, exclude=keep,
                                       real=[Path(r) for r in args.quantize_real], **common)
        print(fp32.summary().replace(f"wrote {fp32.path}", "exported (float32, temporary)"))
        print(quant.summary())
        return 0
    if form == "sweep":  # the stream graph with the polar→Cartesian drawing in front (docs/sweep-form.md)
        from radar_odom_export.sweep_form import export_sweep_checkpoint as export_checkpoint
    report = export_checkpoint(ckpt, out, **common)
    print(report.summary())
    if getattr(args, "budget_said", False):
        print(f"export: {(time.perf_counter() - args.started) / 60:.1f} min in all, calibration included "
              f"(budget {args.calibration_minutes:g} min: --calibration-minutes)")
    return 0


def check_calibration_minutes(args) -> None:
    """`ConfigError` in one line for a ``--calibration-minutes`` that is no budget (negative, not finite, beyond a
    week), before any work."""
    from radar_odom.budgets import check_budget_minutes

    check_budget_minutes(args.calibration_minutes, "--calibration-minutes")


def default_search(checkpoint, form: str | None) -> str:
    """The search a user's checkpoint is exported with when ``--search`` is not given: the fast
    search, as the shipped models are written; exhaustive where the fast one does not exist (the
    pair form, a dual-mode profile whose state is the previous sweep, a rotation step that does not
    divide the turn, which its polar rotation needs)."""
    from radar_odom_export.checkpoint import read_checkpoint_dict
    from radar_odom_export.correlation import divides_turn

    if form == "sequence":
        return "fast"  # the only search the sequence form has
    profile = read_checkpoint_dict(checkpoint)["profile"]
    if form == "pair" or profile.get("mode", "single") == "dual" or not divides_turn(profile["rotation_step_rad"]):
        return "exhaustive"
    return "fast"


def check_fast_rotation(checkpoint, search: str) -> None:
    """`ConfigError` for ``--search fast`` on a profile whose yaw step does not divide the full turn
    (the fast search's polar rotation needs it; `correlation.divides_turn`): said in one line before
    any calibration or tracing, with what to do."""
    import math

    from radar_odom.errors import ConfigError
    from radar_odom_export.checkpoint import read_checkpoint_dict
    from radar_odom_export.correlation import divides_turn

    if search != "fast":
        return
    step = read_checkpoint_dict(checkpoint)["profile"]["rotation_step_rad"]
    if not divides_turn(step):
        raise ConfigError(f"--search fast: the profile's yaw step {math.degrees(step):.4g}° does not divide 360° "
                          f"({360 / math.degrees(step):.3f} steps per turn), which the fast search's polar rotation "
                          "needs; use --search exhaustive, or a rotation_step_rad of 2π/N in the profile")


def calibrate_first(checkpoint, search: str, args) -> None:
    """Calibrate ``checkpoint`` in place if it never was (`radar-odom calibrate`'s defaults, the
    estimates of ``search``), or with ``--no-calibrate`` say loudly, in one line, that it is not."""
    import sys

    from radar_odom_export.calibrate import is_calibrated

    own_budget = args.calibration_minutes != DEFAULT_CALIBRATION_MINUTES  # given, so said where it cannot apply
    if is_calibrated(checkpoint):
        if args.calibration_data:
            print(f"note: {checkpoint} is calibrated already: --calibration-data unused (`radar-odom calibrate "
                  f"{checkpoint} DATA…` calibrates it again)", file=sys.stderr)
        if own_budget:
            print(f"note: {checkpoint} is calibrated already: --calibration-minutes unused", file=sys.stderr)
        return
    if args.no_calibrate:
        print(f"radar-odom export: warning: {checkpoint} was never calibrated (--no-calibrate): the model's "
              "covariance is the raw softmax moment, not a 1σ, so most estimates will come out prior_dominated; "
              f"run `radar-odom calibrate {checkpoint}` first, or export without --no-calibrate", file=sys.stderr)
        if own_budget:
            print("note: --no-calibrate: --calibration-minutes unused", file=sys.stderr)
        return
    from radar_odom_export.calibrate import run_from_args

    from . import calibrate

    fit_search = search if search in ("exhaustive", "fast") else "fast"  # calibrate fits these two (decoupled: fast)
    minutes = args.calibration_minutes or None
    budget = ""
    if minutes is not None:
        import time

        started = getattr(args, "started", None) or time.perf_counter()
        end = time.localtime(time.time() + 60.0 * minutes - (time.perf_counter() - started))
        budget = (f"; within the {minutes:g}-minute budget of this export (--calibration-minutes), the ONNX file "
                  f"written by {time.strftime('%H:%M:%S', end)} local time")
        args.budget_said = True
    print(f"{checkpoint}: no calibrated covariance yet: calibrating it first, in place, as `radar-odom calibrate "
          f"{checkpoint}` would ({fit_search} search"
          + (", on --calibration-data" if args.calibration_data else ", simulated held-out drives")
          + f"; --no-calibrate skips this){budget} ...", flush=True)
    cal_args = calibrate.default_args(str(checkpoint), search=fit_search, data=list(args.calibration_data or []),
                                      threads=args.threads, minutes=minutes or 0.0)
    if minutes is not None:  # the budget is the export's: it counts from its start and leaves time for the writing
        from radar_odom_export.calibrate import EXPORT_WORK_SHARE

        cal_args.started = getattr(args, "started", None)
        cal_args.work_share = EXPORT_WORK_SHARE
        cal_args.minutes_flag = "--calibration-minutes"
    run_from_args(cal_args)


def check_opset(opset: int) -> None:
    """`ConfigError` for an ``--opset`` no export reaches: below `MIN_EXPORT_OPSET`, or above the newest this
    onnx knows (``onnx.defs.onnx_opset_version()``); said before the checkpoint is traced."""
    import onnx

    from radar_odom.errors import ConfigError

    newest = onnx.defs.onnx_opset_version()
    if not MIN_EXPORT_OPSET <= opset <= newest:
        raise ConfigError(f"--opset {opset}: the export reaches opsets {MIN_EXPORT_OPSET} to {newest} (this onnx's "
                          f"newest); give one of those (default {DEFAULT_OPSET})")
