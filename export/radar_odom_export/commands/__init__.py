"""The torch side's subcommands of ``radar-odom`` (export, train, calibrate, adapt): one module each with
``register(subparsers)``, reaching the runtime's command line through the ``radar_odom.commands`` entry points
of export/pyproject.toml. They may use the runtime's command-line helpers (`radar_odom.commands`); the rest of
this package never imports the command line."""
