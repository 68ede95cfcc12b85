"""``radar-odom simulate OUT --frames N --seed S [--scenario NAME]``: a synthetic drive on disk."""
from __future__ import annotations

from . import help_formatter

HELP = "simulate a Navtech CTS350-X drive and write it in the Oxford Radar RobotCar layout"
SCENARIO_NAMES = ("urban", "heavy_traffic", "open", "highway", "junctions")  # radar_odom.sim.SCENARIOS, kept light
HOST_CLOCK_NAMES = ("perfect", "clean", "radiate")  # radar_odom.sim.host_clock.PRESETS, kept light


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate", help=HELP,
        description=(
            HELP + ": OUT/radar/<first-azimuth µs>.png, OUT/radar.timestamps, "
            "OUT/gt/radar_odometry.csv (Oxford relative poses) and OUT/labels/<same name>.png "
            "(255 where the power comes from the static world). The same seed and scenario give "
            "byte-identical files."
        ),
        formatter_class=help_formatter(),
    )
    p.add_argument("out", metavar="OUT", help="sequence folder to write (created)")
    p.add_argument("--frames", type=int, default=100, help="number of sweeps (4 Hz)")
    p.add_argument("--seed", type=int, default=0, help="names the procedural world, drive and traffic")
    p.add_argument("--scenario", default="urban", choices=SCENARIO_NAMES, help="scenario preset")
    p.add_argument("--host-clock", default="perfect", choices=HOST_CLOCK_NAMES,
                   help="stamp the sweeps as a recording host would: perfect = the true stamps; clean = a sensor's "
                        "own stamps (jitter < 1 ms, rare drops); radiate = fitted to a RADIATE drive (jitter, stalls "
                        "and catch-up runs, duplicated and backwards stamps, drops of 1-8 sweeps, half of them in "
                        "turns). Only the kept sweeps are written, named by their stamps (a duplicate +1 µs) and "
                        "listed in reception order; gt/dropped.csv and gt/true_timestamps.csv give the truth")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    import time

    from ..sim import write_drive

    t0 = time.perf_counter()
    clock = getattr(args, "host_clock", "perfect")
    seq = write_drive(args.out, seed=args.seed, frames=args.frames, scenario=args.scenario,
                      progress=not args.no_progress, host_clock=None if clock == "perfect" else clock)
    dt = time.perf_counter() - t0
    if clock == "perfect":
        print(f"wrote {args.frames} sweeps ({args.scenario}, seed {args.seed}) to {seq} in {dt:.1f} s")
    else:
        kept = len((seq / "radar.timestamps").read_text().splitlines())
        print(f"wrote {kept} of {args.frames} sweeps ({args.scenario}, seed {args.seed}, host clock {clock}: "
              f"{args.frames - kept} dropped) to {seq} in {dt:.1f} s")
    return 0
