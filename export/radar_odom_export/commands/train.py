"""``radar-odom train [DATA...] -o model.pt``: train the masker (or describe a baseline)."""
from __future__ import annotations

import argparse

from radar_odom.commands import threads_arg

DEFAULT_MINUTES = 20.0  # a first run ends in a known time; --resume continues it

HELP = "train the masking network with pose supervision (or the raw / cfar / supervised-mask baselines)"

DESCRIPTION = HELP + """.

DATA are recording folders with ground truth (Oxford, Boreas or MulRan layout); the last 20 %
of them (by order given, at least one) are held out for validation unless --val-data names
them. Without DATA, simulated drives are used: every scenario in --scenarios for every seed
in --sim-seeds (training) and --val-seeds (validation). Simulated drives are converted once
and cached under $RADAR_ODOM_CACHE (default ~/.cache/radar-odom).

Stops at --minutes (default 20, announced with its end time when the command starts) or
--epochs, whichever comes first; `--resume` with the same arguments continues (so it does after
Ctrl-C or SIGTERM, from the last epoch that ended: the line it ends with says which). The budget
covers everything, and a checkpoint exists when it ends: simulated drives are made within 40 %
of it for training and 10 % more for validation (at least one of each; a line says how many of
how many; they are cached, so --resume adds more), a validation pass scores as many pairs as fit
in a tenth of it, and where no time is left to validate, the best validated checkpoint is kept,
or the latest weights, said to be unvalidated, where there is none (docs/training.md). Writes OUTPUT
(the best checkpoint by validation pose error), OUTPUT.state.pt (for --resume), OUTPUT.log.json
and OUTPUT.loss.png; the last line gives the best epoch's validation pose error (grid cells²)
and its validation loss (the trained objective) apart. `radar-odom export OUTPUT` then
calibrates the covariance (unless already calibrated) and writes the ONNX model.
Runs under `torchrun --nproc_per_node=N -m radar_odom train ...` with DistributedDataParallel
(gloo on CPU). Needs the torch side, radar-odom-export (pip install -e ./export)."""


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help=HELP, description=DESCRIPTION,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="*", metavar="DATA", help="recording folders with ground truth (none: simulate)")
    p.add_argument("-o", "--output", required=True, help="checkpoint to write (.pt)")
    g = p.add_argument_group("model")
    g.add_argument("--profile", default=None,
                   help="grid profile name (cart-0.8, cart-0.4, cart-0.2, ...) or a JSON file of GridProfile "
                        "fields (default: cart-0.8; with --distill-from: the teacher's)")
    g.add_argument("--masking", choices=("learned", "raw", "cfar"), default="learned",
                   help="learned: train the U-Net; raw: mask = 1, the raw-scan baseline, nothing trained; "
                        "cfar: a classical CFAR mask on the normalised sweep (profile fields cfar_window_m, "
                        "cfar_alpha, cfar_min_level), nothing trained: for a radar without ground truth to "
                        "train on; needs a profile with input_norm floor-scale, as the named ones have "
                        "(default: %(default)s)")
    g.add_argument("--supervised-masks", action="store_true",
                   help="baseline: train the masks with BCE against the simulator's static labels, no pose loss")
    g.add_argument("--unet-base-channels", type=int, default=None,
                   help="override the profile's U-Net width (paper: 8); stored in the checkpoint's profile")
    g.add_argument("--unet-depth", type=int, default=None, help="override the profile's U-Net depth (paper: 5)")
    g.add_argument("--mask-downsample", type=int, default=None, metavar="N",
                   help="run the masker on a grid N times coarser than the profile's and upsample its mask "
                        "(cart-0.4: 2, the U-Net on 0.8 m/px; 4 costs about a quarter of the masker's time); "
                        "width_px must be divisible by 2**unet_depth × N")
    g.add_argument("--beta-pose", type=float, default=None,
                   help="override the profile's soft-argmax temperature for the pose (paper: 1 on Oxford "
                        "images); stored in the checkpoint's profile")
    g = p.add_argument_group("data")
    g.add_argument("--val-data", nargs="+", default=None, metavar="DIR", help="validation recording folders")
    g.add_argument("--sim-seeds", default="1000-1005", help="training world seeds, e.g. 1000-1005,1010 "
                   "(policy: 1000-1999; default: %(default)s)")
    g.add_argument(
        "--val-seeds", default="2000", help="validation world seeds (policy: 2000-2999; default: %(default)s)"
    )
    g.add_argument(
        "--scenarios",
        default="urban,heavy_traffic,open,highway",
        help="comma-separated simulator scenarios (default: %(default)s)",
    )
    g.add_argument("--frames", type=int, default=200, help="sweeps per simulated drive (default: %(default)s)")
    g.add_argument("--val-frames", type=int, default=None, help="sweeps per validation drive (default: --frames)")
    g.add_argument(
        "--sensor",
        choices=("randomised", "oxford", "radiate"),
        default="randomised",
        help="radar of the simulated training drives: a preset, or randomised: gain, noise floor, "
        "speckle, clutter and geometry drawn per drive around both (default: %(default)s); "
        "validation drives always use the oxford preset",
    )
    g.add_argument("--workers", type=int, default=2, help="processes simulating drives (default: %(default)s)")
    g.add_argument("--real", action="append", default=None, metavar="SEQ",
                   help="a real recording with ground truth (Oxford gt, Boreas/MulRan poses, RADIATE GNSS/INS "
                        "aligned as `run` aligns it) whose pairs (k, k+1 … k+4) are mixed into every epoch of "
                        "simulated training pairs; repeatable")
    g.add_argument("--real-fraction", type=float, default=0.25,
                   help="share of training pairs drawn from the --real recordings (default: %(default)s)")
    g.add_argument("--real-holdout", type=int, default=80,
                   help="sweeps at the end of each --real recording never trained on, kept for an honest "
                        "test (benchmarks/real_drive.py --stretch) (default: %(default)s)")
    g = p.add_argument_group("optimisation")
    g.add_argument("--epochs", type=int, default=30, help="maximum epochs (default: %(default)s)")
    g.add_argument(
        "--minutes",
        type=float,
        default=DEFAULT_MINUTES,
        help="wall-clock budget of this invocation, counted from the command's start (simulating drives "
        "included); the end time is printed at the start; at the budget the run stops mid-epoch, validates "
        "and saves, and the same command with --resume continues it (no time left to validate: the best "
        "validated checkpoint is kept, or the latest weights, said to be unvalidated); 0: no budget, every drive "
        "and --epochs alone; at most a week (default: %(default)s)",
    )
    g.add_argument(
        "--steps-per-epoch",
        type=int,
        default=None,
        help="cap on steps per epoch (validation and checkpointing happen once per epoch)",
    )
    g.add_argument(
        "--lr", type=float, default=1e-3, help="Adam learning rate (paper: 1e-5 on a GPU; default: %(default)s)"
    )
    g.add_argument("--lr-decay", type=float, default=0.9, help="learning-rate factor per epoch (default: %(default)s)")
    g.add_argument("--batch", type=int, default=8, help="pairs per step and process (paper: 5; default: %(default)s)")
    g.add_argument(
        "--pose-loss",
        choices=("mse", "ce", "ce+mse"),
        default=None,
        help="mse: the paper's squared soft-argmax error (in grid cells); ce: cross-entropy of the "
        "candidate softmax against the true pose (Barsan et al. 2018), strong gradients even "
        "when the mean sits on a wrong peak; ce+mse: both (default: ce, what the shipped models were "
        "trained with; mse with --search decoupled, the only loss it takes)",
    )
    g.add_argument(
        "--search",
        choices=("exhaustive", "decoupled"),
        default="exhaustive",
        help="the search the pose loss goes through: exhaustive (the volume of every yaw and shift candidate); "
        "decoupled (yaw from the magnitude spectra, then one translation correlation, as the library's "
        "radar_odom_export.onnx_export.export_decoupled writes it, retired from `radar-odom export`: "
        "docs/latency.md; --pose-loss mse only) (default: %(default)s)",
    )
    g.add_argument(
        "--yaw-weight",
        type=float,
        default=1.0,
        help="weight of the yaw term; errors are measured in grid cells (default: %(default)s)",
    )
    g.add_argument(
        "--rotate-deg",
        type=float,
        default=0.0,
        help="augment by rotating both sweeps by a common random angle within ±this (default: off)",
    )
    g.add_argument("--no-mirror", action="store_true", help="disable the left/right mirror augmentation")
    g.add_argument("--no-swap", action="store_true", help="disable the swap-pair-order augmentation")
    g.add_argument("--seed", type=int, default=0, help="seed of initial weights, shuffling, augmentation")
    g.add_argument("--threads", type=threads_arg, default=None,
                   help="torch threads per process (default: cores / processes)")
    g.add_argument("--resume", action="store_true", help="continue from OUTPUT.state.pt")
    g.add_argument(
        "--init-from",
        default=None,
        metavar="CKPT",
        help="start from another checkpoint's weights (same U-Net size), e.g. a cart-0.8 model for "
        "cart-0.4, whose U-Net runs on the same 0.8 m/px grid (mask_downsample 2)",
    )
    g.add_argument(
        "--symmetric-masker",
        action="store_true",
        help="keep every masker kernel left/right symmetric while training (each the mean of itself and its "
        "column flip), so the masker, and with it the graph, is mirror-equivariant: no yaw from a handed "
        "masker on straight roads (docs/yaw-precision.md); the checkpoint holds plain symmetric weights",
    )
    g.add_argument(
        "--distill-from",
        default=None,
        metavar="CKPT",
        help="distil: train this model's masker (e.g. a narrower one: --unet-base-channels 4) to reproduce the "
        "frozen CKPT's masks (a shipped name such as cart-0.4, or a file), each target averaged with the mirror "
        "image of the teacher's masks of the mirrored sweep so that the student is not left/right handed; loss: "
        "the masks' mean squared difference; the profile is the teacher's but for the U-Net size; calibrate "
        "the result before exporting (docs/training.md, 'A narrower masker, distilled')",
    )
    g.add_argument("--distill-pose-weight", type=float, default=0.0, metavar="W",
                   help="with --distill-from: add W × the pose cross-entropy of the student's correlation volume "
                        "to the mask loss (default: %(default)s, masks alone)")
    p.set_defaults(func=run, interrupted=lambda args, exc: saved_epoch_hint(args, args.output, "train"))


def saved_epoch_hint(args, checkpoint, command: str) -> str:
    """What an interrupted `train` (or `adapt`, whose training writes ``checkpoint``) leaves to resume from: the
    state of the last epoch that ended (``CHECKPOINT.state.pt``, written whole at each epoch's end) and how to go on;
    the steps since that epoch ended are lost. A state this command did not write (the one `note_state` saw at its
    start, unchanged) is an earlier run's, unless this one resumed it."""
    from pathlib import Path

    from radar_odom_export.train import read_resume_state, state_path

    state = state_path(checkpoint)
    ours = state.is_file() and (getattr(args, "resume", False) or _stamp(state) != getattr(args, "state_seen", None))
    if not ours:
        cached = " (the drives built so far are cached)" if command == "train" else ""
        return f"no epoch had ended, so nothing is saved to resume: the same command again starts over{cached}"
    which = f"epoch {int(read_resume_state(checkpoint)['epoch'])}"  # written whole (os.replace): never half an epoch
    again = "the same command with --resume continues from there" + (
        " (the recordings are read and labelled again first)" if command == "adapt" else "")
    return f"{Path(state).name} holds {which}: {again}; the steps since are lost"


def note_state(args, checkpoint) -> None:
    """Remember the resume state beside ``checkpoint`` as this command found it (`saved_epoch_hint`)."""
    from radar_odom_export.train import state_path

    args.state_seen = _stamp(state_path(checkpoint))


def _stamp(path):
    """(mtime ns, size) of ``path``, or None where there is none."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


def run(args) -> int:
    from radar_odom.errors import MissingExtraError

    try:
        import torch  # noqa: F401
    except ImportError as exc:
        raise MissingExtraError("torch", "export") from exc
    from radar_odom_export.train import run_from_args

    note_state(args, args.output)  # an interrupt's line tells this run's saved epoch from an earlier run's
    run_from_args(args)
    return 0
