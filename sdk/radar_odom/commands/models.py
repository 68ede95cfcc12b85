"""``radar-odom models``: the model registry (shipped and local models) as a table; ``--add`` / ``--remove``."""
from __future__ import annotations

from . import help_formatter

HELP = "list the shipped and local models with their digests; add or remove a local model"

DESCRIPTION = HELP + """.

Every model `radar_odom.pretrained(NAME)` and `--model NAME` load is listed in a registry with its
SHA-256 and size, checked each time it is loaded (a damaged or replaced file is an error that names
it, both digests and what to do). The table gives each model's grid, form, search, size and digest,
and whether its file matches; under it, what it was trained and calibrated on (from the file's
metadata) and, for a shipped model, the summary line of the docs/scorecard.md section that judged it.
Exit status 1 when a registered file is missing or differs.

Your own models: `radar-odom models --add NAME FILE.onnx` copies FILE (a model written by
`radar-odom export`, `adapt`, ...) to $RADAR_ODOM_HOME/models/NAME.onnx (default ~/.radar-odom) and
records its digest in $RADAR_ODOM_HOME/models/registry.json; `--model NAME` and pretrained(NAME) then
load it with the same check. A shipped name cannot be taken. That registry is a JSON file you may
also write by hand, beside the files it lists:

  {"format": "radar-odom-registry/1",
   "models": {"NAME": {"file": "NAME.onnx", "sha256": "<64 hex digits>", "size": <bytes>}}}

(optional fields: grid, form, search, trained_on, calibrated_on, scorecard; --add fills them in)."""


def register(subparsers) -> None:
    import argparse

    class Formatter(help_formatter(), argparse.RawDescriptionHelpFormatter):
        pass

    p = subparsers.add_parser("models", help=HELP, description=DESCRIPTION, formatter_class=Formatter)
    what = p.add_mutually_exclusive_group()
    what.add_argument("--add", nargs=2, metavar=("NAME", "FILE.onnx"),
                      help="copy FILE.onnx into $RADAR_ODOM_HOME/models as NAME and register it with its digest")
    what.add_argument("--remove", metavar="NAME", help="remove the local model NAME (its file and its entry)")
    p.add_argument("--force", action="store_true", help="with --add: replace a local model of that name")
    p.add_argument("--json", action="store_true", help="print the registry entries as JSON (full digests, paths)")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    from .. import model_registry
    from ..errors import ConfigError

    if args.force and not args.add:
        raise ConfigError("--force goes with --add NAME FILE.onnx")
    if args.add:
        name, file = args.add
        entry = model_registry.add_local(name, file, force=args.force)
        print(f"added {name}: {file} copied to {entry.path} (sha256 {entry.sha256}, {entry.size} bytes), "
              f"listed in {entry.registry}; load it with --model {name} or radar_odom.pretrained({name!r})")
        return 0
    if args.remove:
        path = model_registry.remove_local(args.remove)
        print(f"removed {args.remove} ({path}) from {model_registry.registry_path(path.parent)}")
        return 0
    rows = table_rows()
    if args.json:
        import json

        print(json.dumps([{"name": e.name, "source": e.source, "path": str(e.path), "check": status,
                           **e.to_json()} for e, status, _ in rows], indent=2, ensure_ascii=False))
    else:
        print(render(rows))
    bad = [problem for _, _, problem in rows if problem]
    for problem in bad:
        print(f"radar-odom models: error: {problem}", file=sys.stderr)
    return 1 if bad else 0


def table_rows(models_dir=None) -> list[tuple]:
    """(entry, check status, problem or None) for every registered model, shipped first."""
    from ..errors import ModelDigestError, ModelNotFoundError
    from ..model_registry import check_file
    from ..model_zoo import registry_entries

    rows = []
    for e in registry_entries(models_dir):
        try:
            check_file(e)
            rows.append((e, "ok", None))
        except ModelNotFoundError as exc:
            rows.append((e, "MISSING", str(exc)))
        except ModelDigestError as exc:
            rows.append((e, "DIGEST DIFFERS", str(exc)))
    return rows


def render(rows) -> str:
    """The table, then each model's training, calibration and scorecard lines."""
    import textwrap

    from .. import model_registry
    from ..model_zoo import MODELS_DIR

    n_local = sum(1 for e, _, _ in rows if e.source == "local")
    lines = [f"{len(rows) - n_local} shipped models ({MODELS_DIR}), {n_local} local "
             f"({model_registry.local_dir()}; radar-odom models --add NAME FILE.onnx)"]
    if not rows:
        return lines[0] + "\nno models registered"
    head = ("name", "source", "grid", "form", "search", "size (bytes)", "sha256 (first 16)", "file")
    table = [head] + [(e.name, e.source, e.grid or "-", e.form or "-", e.search or "-", str(e.size), e.sha256[:16],
                       status) for e, status, _ in rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(head))]
    lines.append("")
    for r in table:
        cells = [c.rjust(w) if i == 5 else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))]
        lines.append("  ".join(cells).rstrip())
    for e, _, _ in rows:
        lines += ["", e.name]
        details = [("sha256", e.sha256), ("file", str(e.path)),
                   ("trained on", e.trained_on or "not recorded"), ("calibrated on", e.calibrated_on or "not recorded")]
        if e.scorecard:
            sc = e.scorecard
            text = f"{sc.get('date', '')}, docs/scorecard.md \"{sc.get('section', '')}\": \"{sc.get('line', '')}\""
            details.append(("scorecard", text + (f" ({sc['note']})" if sc.get("note") else "")))
        elif e.source == "shipped":
            details.append(("scorecard", "no scorecard section in docs/scorecard.md"))
        for key, value in details:
            lines.append(textwrap.fill(value, width=110, initial_indent=f"  {key:<14} ",
                                       subsequent_indent=" " * 17, break_on_hyphens=False))
    return "\n".join(lines)
