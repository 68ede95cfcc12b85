"""Subcommands of ``radar-odom``: one module each, defining ``register(subparsers)``.

``register`` only declares arguments (imports nothing heavy, so ``--help`` is instant) and sets
``func`` to a callable taking the parsed ``args`` that does the work, importing what it needs.
A command module is listed here only once it works.
"""
COMMANDS: list[str] = [
    "export",
    "run",
    "demo",
    "train",
    "calibrate",
    "adapt",
    "simulate",
    "profile",
]


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
    try:
        return check_threads(value, "--threads")
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
