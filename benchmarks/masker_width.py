"""What a narrower masker buys: untrained cart-0.4 graphs with other U-Net sizes, timed against the shipped file.

    python benchmarks/masker_width.py 4x5 4x4 2x5 6x5 --out /tmp/masker-width     # BASExDEPTH each; ≈ 1.5 min

Each student is the shipped cart-0.4 checkpoint's profile with only ``unet_base_channels`` and ``unet_depth``
changed, seeded random weights (weights do not change the time), exported with the shipped file's own fast-search
settings (`model_zoo.shipped_export`), then stepped interleaved with the shipped file in one process
(`compare_graphs.py`, whose table this prints). docs/latency.md, "A distilled masker".
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path


def export_student(base: int, depth: int, out: Path) -> Path:
    """The shipped cart-0.4 with a seeded, untrained U-Net of ``base`` channels, ``depth`` levels: OUT/sBxD.onnx."""
    import torch

    from radar_odom.model_zoo import shipped_export
    from radar_odom.profiles import GridProfile
    from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint, write_checkpoint_dict
    from radar_odom_export.model import MaskedCorrelator
    from radar_odom_export.onnx_export import export_checkpoint

    teacher = read_checkpoint_dict(resolve_checkpoint("cart-0.4"))
    profile = GridProfile.from_dict(teacher["profile"]).with_(unet_base_channels=base, unet_depth=depth)
    torch.manual_seed(0)
    state = MaskedCorrelator(profile, masking="learned").state_dict()
    ckpt = out / f"s{base}x{depth}.pt"
    write_checkpoint_dict(ckpt, {**teacher, "profile": asdict(profile), "state_dict": dict(state)})
    onnx = ckpt.with_suffix(".onnx")
    export_checkpoint(ckpt, onnx, search="fast", search_settings=shipped_export("cart-0.4")["settings"], verify=False)
    return onnx


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="+", help="U-Net sizes as BASExDEPTH (the shipped: 8x5)")
    ap.add_argument("--out", default="masker-width", help="folder for the exports (default: %(default)s)")
    ap.add_argument("--steps", type=int, default=200, help="timed steps per graph (default: %(default)s)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes]
    except ValueError:
        sys.exit(f"sizes must read BASExDEPTH, e.g. 4x5; got {args.sizes}")
    files = [str(export_student(b, d, out)) for b, d in sizes]
    from compare_graphs import main as compare

    return compare(["cart-0.4", *files, "--steps", str(args.steps)])


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    sys.exit(main())
