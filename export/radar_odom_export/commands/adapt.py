"""``radar-odom adapt RECORDING... -o model.onnx``: fine-tune a shipped model on your own radar, no reference."""
from __future__ import annotations

import argparse

from radar_odom.commands import cli_warnings, threads_arg

HELP = "adapt a shipped model to your radar from its own recordings (no ground truth needed)"

DESCRIPTION = HELP + """.

Runs the model over the recordings as `radar-odom run` would, turns each step onto the chord a
car drives (a car does not slide sideways: over one sweep it moves in the direction of half its
turn), labels every pair of sweeps up to --max-skip apart with the composition of those steps,
and fine-tunes the masker on them, mixed with simulated pairs so it forgets nothing. It also
measures the radar's mount yaw on the car (the direction of its straight steps) and writes it
into the model: the runtime turns every match by it. The last --holdout of each recording is
never trained on: it picks the best epoch, and there the fine-tuned masker is kept only if its
matches compose at least as well as the base's (A→C against A→B∘B→C: no reference needed) and
it did not collapse toward standing still; else the base's masker is written with its mount yaw
(--keep forces the choice). The report compares shipped, base + mount and fine-tuned + mount
there (KITTI too where the recording has a reference). Writes OUTPUT (.onnx, searching like the
base), the checkpoint beside it (.pt) and the report (.adapt.json). Interrupted? Run the same
command with --resume. Needs the torch side, radar-odom-export (pip install -e ./export). About 15 min
for 230 sweeps on 2 CPU cores.
Under `torchrun --nproc_per_node=N -m radar_odom adapt ...` the ranks train together; rank 0 writes (docs/fleet.md)."""


def register(subparsers) -> None:
    from radar_odom.commands import help_formatter

    class Formatter(help_formatter(), argparse.RawDescriptionHelpFormatter):
        pass

    p = subparsers.add_parser("adapt", help=HELP, description=DESCRIPTION, formatter_class=Formatter)
    p.add_argument("recordings", nargs="+", metavar="RECORDING",
                   help="recording folders or ROS bags, anything `radar-odom run` reads; no reference needed")
    p.add_argument("-o", "--output", required=True, help="the adapted model, an .onnx file")
    p.add_argument("--from", dest="base", default="cart-0.4",
                   help="a shipped model's name or a checkpoint (.pt) from `radar-odom train`")
    p.add_argument("--minutes", type=float, default=12.0,
                   help="budget for simulating the drives not yet cached (at most 40 %% of it) and training, "
                        "minutes (> 0, at most a week); reading and labelling the recordings come first and are "
                        "not counted")
    p.add_argument("--epochs", type=int, default=4,
                   help="validations on the held-out stretch (the best is kept); the budget may end sooner")
    p.add_argument("--lr", type=float, default=2e-4, help="learning rate (Adam)")
    p.add_argument("--real-fraction", type=float, default=0.7,
                   help="share of each batch taken from the recordings; the rest are simulated pairs")
    p.add_argument("--max-skip", type=int, default=4, help="pairs up to this many sweeps apart are trained on")
    p.add_argument("--holdout", type=float, default=0.2,
                   help="share of each recording, at its end, never trained on (validation and report)")
    p.add_argument("--no-vehicle-prior", action="store_true",
                   help="keep the runtime's step directions and measure no mount yaw (for a radar not on a car)")
    p.add_argument("--keep", choices=("auto", "fine-tuned", "base"), default="auto",
                   help="which masker to write: auto picks by the held-out self-consistency")
    p.add_argument("--sweeps", default=None, metavar="A:B",
                   help="use sweeps A..B-1 of each recording only (Python slice, e.g. :200); default: all")
    p.add_argument("--topic", default=None, help="the radar topic of a ROS bag (default: its only radar topic)")
    p.add_argument("--threads", type=threads_arg, default=None,
                   help="torch and onnxruntime threads (default: all cores)")
    p.add_argument("--ray", action="store_true",
                   help="label the recordings in parallel as Ray tasks (the fleet extra; a local Ray unless "
                        "--address); the training stays on this machine (docs/fleet.md)")
    p.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                   help="label on this running Ray cluster (implies --ray); its nodes must see the recordings")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run writing the same OUTPUT")
    p.add_argument("--force", action="store_true", help="overwrite OUTPUT if it exists")
    p.set_defaults(func=run, interrupted=interrupted)


def interrupted(args, exc) -> str:
    """What `radar-odom adapt` adds to its interrupted line: its training's last saved epoch, for --resume."""
    from pathlib import Path

    from .train import saved_epoch_hint

    return saved_epoch_hint(args, Path(args.output).with_suffix(".pt"), "adapt")


def run(args) -> int:
    from pathlib import Path

    from radar_odom.errors import MissingExtraError, OutputError

    from .train import note_state

    try:
        import torch  # noqa: F401

        from radar_odom_export.adapt import AdaptConfig, adapt, format_report, parse_sweeps
        from radar_odom_export.train import init_distributed, shutdown_distributed
    except ImportError as exc:
        raise MissingExtraError(getattr(exc, "name", None) or "torch", "export") from exc
    out = Path(args.output)
    note_state(args, out.with_suffix(".pt"))  # an interrupt's line tells this run's saved epoch from an earlier run's
    if out.exists() and not (args.force or args.resume):
        raise OutputError(f"{out} exists; pass --force to overwrite it, or -o to write elsewhere")
    cfg = AdaptConfig(base=args.base, minutes=args.minutes, epochs=args.epochs, lr=args.lr,
                      real_fraction=args.real_fraction, max_skip=args.max_skip, holdout_fraction=args.holdout,
                      vehicle_prior=not args.no_vehicle_prior, threads=args.threads, resume=args.resume, keep=args.keep,
                      info={"command": "radar-odom adapt " + " ".join(Path(r).name for r in args.recordings)
                                    + (f" --sweeps {args.sweeps}" if args.sweeps else "")})
    labeller = None
    if args.ray or args.address:
        from radar_odom.fleet.scheduler import import_ray
        from radar_odom_export.adapt_labels import ray_labeller

        import_ray()  # the install line now, not after the base model is prepared
        labeller = ray_labeller(args.address)
    d = init_distributed()  # torchrun's ranks (docs/fleet.md); one process otherwise
    try:
        with cli_warnings("adapt"):
            report = adapt(args.recordings, out, cfg, topic=args.topic, sweeps=parse_sweeps(args.sweeps),
                           labeller=labeller, dist=d)
        d.barrier()  # every rank at the end before the group goes (as train: a rank leaving early could abort)
    finally:
        shutdown_distributed(d)
    if report is None:  # a rank other than 0: it trained its shard, rank 0 writes and reports
        return 0
    print(format_report(report))
    print(f"wrote {out}, {out.with_suffix('.pt')} and {out.with_suffix('.adapt.json')}")
    return 0
