"""``radar-odom fleet RECORDING... -o OUT [--address auto|HOST:PORT]``: `run` over many recordings on Ray."""
from __future__ import annotations

from . import threads_arg

HELP = "odometry over many recordings as Ray tasks (this machine or a cluster), resumable, with a fleet report"
DESCRIPTION = HELP + (
    ". Each recording's outputs are exactly `radar-odom run`'s, written atomically to OUT/<recording name>/ "
    "with a manifest (fleet-done.json). OUT/<recording name> must be new or hold fleet's own earlier outputs of "
    "that recording: anything else there, or an OUT inside a recording (or holding one), is refused before any "
    "work. The same command again skips the recordings whose outputs are complete "
    "and valid for their inputs, the model and the options. A recording that fails is tried once more, then "
    "listed with its reason while the others go on. Writes OUT/fleet.csv (one row per recording) and "
    "OUT/fleet.md (summary, worst drives, error against speed and length). Needs the fleet extra (Ray): "
    "pip install \"radar-odom[fleet]\". docs/fleet.md: clusters, costs, limits."
)
EPILOG = ("exit status: 0 every recording done with every sweep; 3 all done but some sweeps were skipped "
          "(see skipped_sweeps in fleet.csv); 1 a recording failed (its reason in fleet.csv and on stderr) "
          "or an error stopped the fleet; 130 Ctrl-C, 143 SIGTERM: the recordings done so far are kept, the same "
          "command again runs the others")
EXIT_OK, EXIT_ERROR, EXIT_SKIPPED = 0, 1, 3


def register(subparsers) -> None:
    from .run import register_recording_options

    p = subparsers.add_parser("fleet", help=HELP, description=DESCRIPTION, epilog=EPILOG)
    p.add_argument("recordings", nargs="+", metavar="RECORDING",
                   help="recording folders or ROS bags, anything `radar-odom run` reads (on a cluster: at the "
                        "same path on every node)")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output folder: OUT/<recording>/ per recording, OUT/fleet.csv, OUT/fleet.md")
    p.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                   help="a running Ray cluster ('auto': the one this machine belongs to); default: start a local "
                        "Ray on this machine for this command")
    p.add_argument("-m", "--model", default=None,
                   help="exported .onnx file, or the name of a shipped model; default: as `radar-odom run`")
    p.add_argument("--threads", type=threads_arg, default=None,
                   help="onnxruntime threads per recording (default: one per CPU when there are at least as many "
                        "recordings as CPUs, else the CPUs shared among them); each node runs CPUs // threads "
                        "recordings at once")
    p.add_argument("--no-progress", action="store_true", help="no progress line")
    register_recording_options(p)
    p.set_defaults(func=run, interrupted=interrupted)


def interrupted(args, exc) -> str:
    """What `radar-odom fleet` adds to its interrupted line: the recordings done so far (each published whole, with
    its manifest) stay, and the same command again runs only the others."""
    from pathlib import Path

    from ..fleet.manifest import MANIFEST, recording_names

    out = Path(args.output)
    names = recording_names([str(r) for r in args.recordings])
    done = sum((out / name / MANIFEST).is_file() for name in names)
    return (f"{done} of {len(names)} recordings are done and kept in {out} (each written whole); the same command "
            "again runs only the others and writes the report")


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..errors import OutputError
    from ..fleet.report import DONE, FAILED, KEPT, check_reports, claim_reports, write_csv, write_summary
    from ..fleet.scheduler import check_ray_address, import_ray, run_fleet
    from ..model_zoo import default_model_name, resolve_model
    from .run import sequence_options

    check_ray_address(args.address)  # `garbage`, `host:text`: refused before Ray is asked anything
    import_ray()  # the one-line install hint before anything else
    options = sequence_options(args)
    model = resolve_model(args.model or default_model_name())
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder; give -o a folder (new, or an earlier fleet's)")
    check_reports(out)  # the recordings' own folders are checked by run_fleet, all before any work
    fleet = run_fleet(args.recordings, out, model, options, address=args.address, threads=args.threads,
                      show_progress=not args.no_progress)
    rows = fleet.rows
    claim_reports(out)
    csv_path = write_csv(out / "fleet.csv", rows)
    md_path = write_summary(out, rows, command=f"radar-odom fleet ({len(rows)} recordings) -o {out}")
    done, kept = sum(r["status"] == DONE for r in rows), sum(r["status"] == KEPT for r in rows)
    pace = (f"; {fleet.threads} thread(s) per recording on {fleet.workers} worker(s), {fleet.nodes} node(s)"
            if fleet.workers else "")
    print(f"{len(rows)} recordings: {done} done, {kept} kept (done by an earlier run), {len(fleet.failed)} failed "
          f"in {fleet.wall_s:.1f} s{pace}")
    print(f"report: {csv_path}, {md_path}")
    for r in rows:
        if r["status"] == FAILED:
            print(f"radar-odom fleet: failed {r['path']} (after {r['attempts']} attempts): {r['reason']}",
                  file=sys.stderr)
    if fleet.failed:
        return EXIT_ERROR
    return EXIT_SKIPPED if any(int(r["skipped_sweeps"] or 0) for r in rows) else EXIT_OK
