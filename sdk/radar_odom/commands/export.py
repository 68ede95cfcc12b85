"""``radar-odom export model.pt [-o model.onnx] [--form stream|pair|sequence] [--search exhaustive|fast]
[--opset N] [--exporter auto|dynamo|torchscript] [--quantize int8]``.

A shipped name (``radar-odom export cart-0.4``) reproduces the shipped model: its search, search
settings and form are read from the shipped ONNX file's metadata (``radar_odom.search``,
``radar_odom.form``) unless ``--search`` / ``--form`` say otherwise."""
from __future__ import annotations

from ..model_file import DEFAULT_OPSET, MIN_EXPORT_OPSET
from ..model_zoo import shipped_export  # noqa: F401  (re-exported: its home is radar_odom.model_zoo)
from ..outputs import check_output_path  # noqa: F401  (re-exported: its home is radar_odom.outputs)

HELP = "export a trained checkpoint to one self-contained ONNX graph (sweep in, pose + covariance out)"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help=HELP, description=HELP + ". Needs the export extra (torch, onnx, onnxscript)."
    )
    p.add_argument("checkpoint", help="checkpoint written by `radar-odom train` (.pt), or the name of a "
                                      "shipped one (cart-0.8, cart-0.4): the weights of the pretrained models")
    p.add_argument("-o", "--output", default=None,
                   help="ONNX file to write (default: the checkpoint's name, or NAME for a shipped one, with the "
                        "search and form appended where they are not its default, e.g. cart-0.4-exhaustive.onnx)")
    p.add_argument("--force", action="store_true", help="overwrite the output file if it exists")
    p.add_argument("--form", choices=("stream", "pair", "sequence"), default=None,
                   help="stream: (sweep, previous state) -> (pose, covariance, state), masks each sweep once; "
                        "pair: (previous sweep, sweep) -> (pose, covariance), for evaluation; sequence: T "
                        "consecutive sweeps -> T-1 poses and covariances in one call, for offline batches "
                        "(radar_odom.match_sequence; fast search). Default: stream")
    p.add_argument("--search", choices=("exhaustive", "fast"), default=None,
                   help="exhaustive: score every yaw candidate (the paper's search); fast: coarse-to-fine yaw "
                        "search, several times faster on a CPU, stream and sequence forms (default: a shipped "
                        "name's own search, read from the shipped model; else exhaustive, fast for --form "
                        "sequence). The decoupled search (Fast-MbyM) is retired from the CLI: 27 %% less "
                        "accurate and not fast enough to pay for it (docs/latency.md)")
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET,
                   help=f"ONNX opset to write, {MIN_EXPORT_OPSET} or later; the written file is checked to have it "
                        f"(default: {DEFAULT_OPSET})")
    p.add_argument("--exporter", choices=("auto", "dynamo", "torchscript"), default="auto",
                   help="torch.onnx exporter; auto: dynamo, falling back to TorchScript only if the dynamo "
                        "exporter itself fails (default: auto)")
    p.add_argument("--quantize", choices=("int8",), default=None,
                   help="int8: quantise the masker's Conv nodes (static QDQ, int8 weights per channel, uint8 "
                        "activations, percentile calibration on simulated validation drives, seeds 2000-2001); "
                        "the correlation stays float32. "
                        "Verified against the float32 export on held-back simulated sweeps (--no-verify skips "
                        "this too); recorded in the "
                        "metadata as radar_odom.quantization (default: float32 throughout)")
    p.add_argument("--quantize-float", default="first,last", metavar="first,last|none",
                   help="with --quantize: which of the masker's Conv nodes stay float32: first, last, both, or "
                        "none (default: %(default)s)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip the onnxruntime-vs-torch check on fresh random sweeps (a difference beyond the "
                        "tolerance fails the export and writes nothing)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..errors import MissingExtraError, OutputError

    try:
        from radar_odom_export.checkpoint import resolve_checkpoint
        from radar_odom_export.onnx_export import export_checkpoint
    except ImportError as exc:  # torch / onnx missing: say which extra to install
        raise MissingExtraError(getattr(exc, "name", None) or "torch", "export") from exc
    check_opset(args.opset)
    ckpt = resolve_checkpoint(args.checkpoint)
    shipped = None if Path(args.checkpoint).is_file() else shipped_export(ckpt.stem)
    form, settings = args.form, None
    if shipped is not None and args.search in (None, shipped["search"]) and args.form in (None, shipped["form"]):
        # reproduce the shipped model: its search with its settings, its form
        search, form, settings = shipped["search"], shipped["form"], shipped["settings"]
        tag = ""
    else:
        search = args.search or ("fast" if args.form == "sequence" else "exhaustive")
        plain = shipped is None and search == "exhaustive" and form in (None, "stream")
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
    common = dict(form=form, opset=args.opset, verify=not args.no_verify, search=search,
                  exporter=args.exporter)
    if settings is not None:
        common["search_settings"] = settings
    if args.quantize:
        try:
            from radar_odom_export.quantize import export_quantized
        except ImportError as exc:
            raise MissingExtraError(getattr(exc, "name", None) or "onnxruntime", "export") from exc
        keep = "" if args.quantize_float == "none" else args.quantize_float
        fp32, quant = export_quantized(ckpt, out, quantize=args.quantize, exclude=keep, **common)
        print(fp32.summary().replace(f"wrote {fp32.path}", "exported (float32, temporary)"))
        print(quant.summary())
        return 0
    report = export_checkpoint(ckpt, out, **common)
    print(report.summary())
    return 0


def check_opset(opset: int) -> None:
    """`ConfigError` for an ``--opset`` no export reaches: below `MIN_EXPORT_OPSET`, or above the newest this
    onnx knows (``onnx.defs.onnx_opset_version()``); said before the checkpoint is traced."""
    import onnx

    from ..errors import ConfigError

    newest = onnx.defs.onnx_opset_version()
    if not MIN_EXPORT_OPSET <= opset <= newest:
        raise ConfigError(f"--opset {opset}: the export reaches opsets {MIN_EXPORT_OPSET} to {newest} (this onnx's "
                          f"newest); give one of those (default {DEFAULT_OPSET})")
