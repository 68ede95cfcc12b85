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
    "simulate",
    "profile",
]
