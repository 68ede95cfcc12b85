"""The ``radar-odom`` command line: one entry point, one subcommand per job.

The runtime's commands are modules of this package; the torch side's (`TORCH_COMMANDS`: export, train,
calibrate, adapt) come from the ``radar-odom-export`` distribution through the entry-point group
`ENTRY_POINT_GROUP`. Without it they are listed all the same, and running one says how to install it
instead of "invalid choice".
"""
from __future__ import annotations

import argparse
import importlib
import sys
from importlib import metadata

from .. import __version__
from ..errors import MissingExtraError, RadarOdomError
from . import COMMANDS, ENTRY_POINT_GROUP, TORCH_COMMANDS
from .interrupts import command_hint, exit_status, interrupted_line, sigterm_interrupts


def plugin_commands() -> dict[str, metadata.EntryPoint]:
    """The subcommands installed distributions register in `ENTRY_POINT_GROUP` (name -> entry point)."""
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def missing_command_error(name: str) -> MissingExtraError:
    """What running a torch-side command says where radar-odom-export is not installed."""
    return MissingExtraError("radar_odom_export", "export",
                             subject=f"`radar-odom {name}` is part of the torch side, the radar-odom-export "
                                     "distribution, which is not installed")


def _register_missing(sub, name: str) -> None:
    """A stand-in subcommand: listed in ``--help`` with its job, and saying how to install it when run."""
    text = str(missing_command_error(name))
    p = sub.add_parser(name, help=f"{TORCH_COMMANDS[name]} (needs radar-odom-export: not installed)",
                       description=text)

    def refuse(args):
        raise missing_command_error(name)

    p.set_defaults(func=refuse, missing_command=True)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="radar-odom",
        description="Learned radar odometry (Masking by Moving) as one ONNX graph.",
    )
    parser.add_argument("--version", action="version", version=f"radar-odom {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    plugins = plugin_commands()
    for name in COMMANDS:
        if name not in TORCH_COMMANDS:
            importlib.import_module(f"radar_odom.commands.{name}").register(sub)
        elif name in plugins:
            plugins[name].load()(sub)
        else:
            _register_missing(sub, name)
    for name in sorted(set(plugins) - set(COMMANDS)):  # another distribution's own commands, after ours
        plugins[name].load()(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    if argv and argv[0] in TORCH_COMMANDS and not {"-h", "--help"} & set(argv[1:]):
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        if sub.choices[argv[0]].get_default("missing_command"):  # its options are unknown here: say what is missing
            print(f"radar-odom {argv[0]}: error: {missing_command_error(argv[0])}", file=sys.stderr)
            return 1
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with sigterm_interrupts():  # SIGTERM unwinds as Ctrl-C does: the work so far is kept (commands/interrupts.py)
            return int(args.func(args) or 0)
    except RadarOdomError as exc:
        print(f"radar-odom {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: one line, what was kept, 130 / 143
        print(interrupted_line(args.command, exc, command_hint(args, exc)), file=sys.stderr)
        return exit_status(exc)


if __name__ == "__main__":
    sys.exit(main())
