"""Subcommands of ``radar-odom``: one module each, defining ``register(subparsers)``.

``register`` only declares arguments (imports nothing heavy, so ``--help`` is instant) and sets
``func`` to a callable taking the parsed ``args`` that does the work, importing what it needs.
A command module is listed here only once it works.

Two distributions provide them (issue 52): the runtime (``radar-odom``: this package) and the torch
side (``radar-odom-export``, built from export/), whose commands (`TORCH_COMMANDS`) live in
``radar_odom_export.commands`` and reach this command line through the entry-point group
`ENTRY_POINT_GROUP`. Where that distribution is not installed each of them is still listed, and says
how to install it (`radar_odom.commands.cli`).
"""
#: every subcommand, in the order ``radar-odom --help`` lists them
COMMANDS: list[str] = [
    "export",
    "run",
    "demo",
    "train",
    "calibrate",
    "adapt",
    "fleet",
    "simulate",
    "profile",
    "models",
]

#: the entry-point group through which an installed distribution adds subcommands: ``name = "module:register"``
ENTRY_POINT_GROUP = "radar_odom.commands"

#: the commands the torch side provides (its pyproject.toml registers them in `ENTRY_POINT_GROUP`), with the
#: one-line help listed when it is not installed
TORCH_COMMANDS: dict[str, str] = {
    "export": "export a trained checkpoint to one ONNX graph",
    "train": "train the masker from pose supervision",
    "calibrate": "tune a checkpoint's covariance temperature",
    "adapt": "fine-tune a model on a user's own recordings",
}


def help_formatter():
    """argparse's defaults-in-help formatter, without the noise of ``(default: None)`` /
    ``(default: [])`` / ``(default: False)`` on options whose help says what their absence means."""
    import argparse

    class DefaultsHelp(argparse.ArgumentDefaultsHelpFormatter):
        def _get_help_string(self, action):
            quiet = action.default is None or action.default is False or action.default == []
            if quiet or "%(default)" in (action.help or ""):
                return action.help
            return super()._get_help_string(action)

    return DefaultsHelp


def print_warnings(command: str, caught, stream=None) -> None:
    """Warnings caught during a command (``warnings.catch_warnings(record=True)``), one line each in the
    command line's language (``radar-odom CMD: warning: …``), never Python's file-and-source-line form."""
    import sys

    stream = sys.stderr if stream is None else stream
    for w in caught:
        print(f"radar-odom {command}: warning: {w.message}", file=stream)


def cli_warnings(command: str):
    """A context in which every warning prints at once as one line in the command line's language
    (``radar-odom CMD: warning: …``), not as Python's ``file:line: Category: …`` with its source line; for
    long commands (`adapt`), where warnings collected to the end (`print_warnings`) would come too late."""
    import contextlib
    import sys
    import warnings

    @contextlib.contextmanager
    def context():
        with warnings.catch_warnings():
            def show(message, category, filename, lineno, file=None, line=None):
                print(f"radar-odom {command}: warning: {message}", file=sys.stderr if file is None else file)

            warnings.showwarning = show
            yield

    return context()


def threads_arg(text: str) -> int:
    """argparse ``type`` of ``--threads``: a whole number ≥ 1, at most a few per CPU
    (`radar_odom.onnx_model.check_threads`); anything else is a usage error naming the value."""
    import argparse

    from ..errors import ConfigError
    from ..onnx_model import check_threads

    try:
        value = int(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of threads (≥ 1)") from None
    if value < 1:  # check_threads's own wording offers None, which no command line can pass
        raise argparse.ArgumentTypeError(f"--threads must be ≥ 1, got {value} (leave it out for one per physical core)")
    try:
        return check_threads(value, "--threads")
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
