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
