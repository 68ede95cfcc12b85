"""The ``radar-odom`` command line: one entry point, one subcommand per job."""
from __future__ import annotations

import argparse
import importlib
import sys

from .. import __version__
from ..errors import RadarOdomError
from . import COMMANDS
from .interrupts import command_hint, exit_status, interrupted_line, sigterm_interrupts


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="radar-odom",
        description="Learned radar odometry (Masking by Moving) as one ONNX graph.",
    )
    parser.add_argument("--version", action="version", version=f"radar-odom {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"radar_odom.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
