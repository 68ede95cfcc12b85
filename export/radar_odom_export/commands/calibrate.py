"""``radar-odom calibrate model.pt [DATA...]``: tune the covariance temperature so mean d² ≈ 3."""
from __future__ import annotations

import argparse

from radar_odom.commands import threads_arg

HELP = "calibrate a checkpoint's covariance on held-out drives (mean d² ≈ 3, per axis)"

DESCRIPTION = HELP + """.

The pose keeps the trained beta_pose; only the covariance changes. First its softmax
temperature (paper Sec. 6.2): beta_cov is swept log-spaced, then bisected until mean d² is in
[2.7, 3.3] (the beta -> mean d² table is printed). Then (--covariance fitted, the default) a
scale of that moment and the quantisation floors of translation and yaw are fitted by maximum
likelihood on every consecutive pair, as --search computes them, so that a sharp peak's
covariance is small and a corridor ridge's large; the per-scenario d² table shows both. The
values are written into the checkpoint's profile (in place, or to -o); `radar-odom export` then
carries them into the graph. Where no temperature brings mean d² into the band (only easy
drives, whose errors sit below the quantisation floor the temperature keeps), --covariance
fitted keeps beta_cov at beta_pose and lets the per-axis fit set the scale, in a note line;
--covariance temperature stops with the table. DATA are recording folders with ground truth;
without DATA, simulated drives of --scenarios x --sim-seeds are used (policy: validation seeds 2000-2999, never the
training or evaluation seeds). --real adds real recordings with a reference (Oxford gt,
Boreas/MulRan poses, a RADIATE GNSS/INS track aligned as `radar-odom run` aligns it), their
last --real-holdout sweeps left out for an honest test; their pairs then carry --real-share of
the per-axis fit (by default all of it: real sweeps have error sources the simulator lacks, and a
few hundred real pairs would otherwise count for little beside thousands of simulated ones).
Needs the torch side, radar-odom-export (pip install -e ./export)."""


def register(subparsers) -> None:
    p = subparsers.add_parser("calibrate", help=HELP, description=DESCRIPTION,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", help="checkpoint written by `radar-odom train`")
    p.add_argument("data", nargs="*", metavar="DATA", help="held-out recording folders with ground truth")
    p.add_argument("-o", "--output", default=None, help="write the calibrated checkpoint here (default: in place)")
    p.add_argument("--sim-seeds", default="2500", help="held-out world seeds without DATA (default: %(default)s)")
    p.add_argument("--scenarios", default="urban,heavy_traffic,open,highway",
                   help="comma-separated simulator scenarios (default: %(default)s)")
    p.add_argument("--frames", type=int, default=120, help="sweeps per simulated drive (default: %(default)s)")
    p.add_argument("--pose-estimator", choices=("soft-argmax", "parabolic"), default=None,
                   help="set how the model reads its pose off the volume before calibrating (default: keep the "
                        "checkpoint's): soft-argmax (paper eq. 3 at beta_pose) or parabolic (sub-cell peak fit)")
    p.add_argument("--covariance", choices=("fitted", "temperature"), default="fitted",
                   help="fitted: the temperature, then per-axis scale and floors by maximum likelihood; "
                        "temperature: beta_cov alone, the paper's (default: %(default)s)")
    p.add_argument("--search", choices=("exhaustive", "fast"), default="fast",
                   help="the yaw search the model will be exported with (`radar-odom export --search`): the "
                        "per-axis fit uses its estimates (default: %(default)s)")
    p.add_argument("--real", action="append", default=None, metavar="SEQ",
                   help="a real recording with a reference, calibrated on as well (repeatable)")
    p.add_argument("--real-holdout", type=int, default=80,
                   help="sweeps at the end of each --real recording left out, as `radar-odom train --real` "
                        "leaves them out (default: %(default)s)")
    p.add_argument("--real-share", type=float, default=1.0,
                   help="share of the per-axis fit's likelihood carried by the --real pairs; the default fits "
                        "the shape on real pairs alone (the simulated drives then set the temperature only), "
                        "as the product is judged on real sweeps (default: %(default)s)")
    p.add_argument("--max-pairs", type=int, default=2000,
                   help="temperature stage: use at most this many pairs, evenly spread (their volumes are kept)")
    p.add_argument("--batch", type=int, default=8, help="pairs per forward pass (default: %(default)s)")
    p.add_argument("--workers", type=int, default=2, help="processes simulating drives (default: %(default)s)")
    p.add_argument("--threads", type=threads_arg, default=None, help="torch threads (default: all cores)")
    p.add_argument("--minutes", type=float, default=0.0,
                   help="wall-clock budget: the simulated drives within its first quarter, then the temperature's "
                        "correlation volumes and the per-axis fit's estimates on as many pairs, spread over every "
                        "drive, as fit in 90 %% of it (at least one drive and one batch); the line after the d² "
                        "table says how many of how many. 0: no budget, every pair (default: %(default)s; at "
                        "most a week)")
    p.set_defaults(func=run)


def default_args(checkpoint: str, **overrides) -> argparse.Namespace:
    """`radar-odom calibrate CHECKPOINT` as the command line would parse it, with ``overrides``
    (e.g. ``search``, ``data``, ``threads``): how `radar-odom export` calibrates a checkpoint that
    is not, with this command's own defaults (one home for them)."""
    parser = argparse.ArgumentParser(prog="radar-odom")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["calibrate", str(checkpoint)])
    for key, value in overrides.items():
        if not hasattr(args, key):
            raise AttributeError(f"radar-odom calibrate has no option {key!r}")
        setattr(args, key, value)
    return args


def run(args) -> int:
    from radar_odom.errors import MissingExtraError

    try:
        import torch  # noqa: F401
    except ImportError as exc:
        raise MissingExtraError("torch", "export") from exc
    from radar_odom_export.calibrate import run_from_args

    run_from_args(args)
    return 0
