"""Band limits of the masked features (`GridProfile.feature_highpass_px`, `feature_blur_px`,
`feature_radial_blur_px`): the shipped masker, unchanged, exported with each setting and measured where
the yaw issue measures.

    python benchmarks/band_limits.py                                   # cart-0.4, the settings below; ≈ 25 min
    python benchmarks/band_limits.py --variants hp12 b1+hp12 --parts real
    python benchmarks/band_limits.py --variants hp12 r1+hp12 --parts curves
    python benchmarks/band_limits.py --checkpoint cart-0.8 --variants hp0 hp6 hp12 --parts real

A variant is ``+``-joined parts: ``hpH`` (high-pass σ = H px), ``bB`` (blur σ = B px), ``rR`` (radial-only
blur σ = R px), e.g. ``b1+hp12``, ``r1+hp12``; a field a variant does not name is off (``hp0`` is the
checkpoint's profile with all three off, whatever the shipped profile sets); ``+mD`` adds a mount yaw of D°
(`radar_odom.mount_yaw_rad`, as `radar-odom adapt` writes it). Each is the checkpoint with those profile
fields, exported with the fast search into a temporary folder (the covariance calibration is the
checkpoint's: pose figures only are comparable across rows; the motion prior's fusion uses the
covariance, so the "defaults" rows of an uncalibrated variant are indicative). Parts (``--parts``):

* ``curves``: `yaw_precision.py --parts curves` (steady simulated bends, estimated/true yaw);
* ``real``: `yaw_precision.py --parts radiate,oxford` (the shared RADIATE drive, the Oxford pair) and
  `real_drive.py --stretch 200:` (the held-out last 80 sweeps: step scale, direction, yaw slope);
* ``sim``: `eval_onnx.py --seeds 5000` (held-out simulated drives, four scenarios, graph alone).

Needs the export extra (torch) and, for ``real``, the shared real sweeps.
"""
from __future__ import annotations

import argparse
import math
import re
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
DEFAULT_VARIANTS = ("hp0", "hp12", "b0.7+hp12", "b1+hp12", "b1.5", "b2")
PARTS = ("curves", "real", "sim")
VARIANT_FIELDS = {"hp": "feature_highpass_px", "b": "feature_blur_px", "r": "feature_radial_blur_px"}


def parse_variant(name: str) -> tuple[dict, float]:
    """({profile field: value}, mount yaw °) of a variant name (module docstring)."""
    fields, mount = {"feature_highpass_px": 0.0, "feature_blur_px": 0.0, "feature_radial_blur_px": 0.0}, 0.0
    for part in name.split("+"):
        m = re.fullmatch(r"(hp|b|r|m)(-?[0-9.]+)", part)
        if m is None:
            raise SystemExit(f"variant {name!r}: parts are hpH, bB, rR and mD (got {part!r})")
        value = float(m.group(2))
        if m.group(1) == "m":
            mount = value
        else:
            fields[VARIANT_FIELDS[m.group(1)]] = value
    return fields, mount


def export_variant(checkpoint: str, name: str, folder: Path) -> Path:
    """The checkpoint with the variant's profile fields, exported (fast search) as ``folder/name.onnx``."""
    import onnx

    from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint, write_checkpoint_dict
    from radar_odom_export.onnx_export import export_checkpoint

    fields, mount = parse_variant(name)
    ckpt = read_checkpoint_dict(resolve_checkpoint(checkpoint))
    ckpt["profile"].update(fields)
    pt = folder / f"{name}.pt"
    write_checkpoint_dict(pt, ckpt)
    out = folder / f"{name}.onnx"
    export_checkpoint(pt, out, search="fast")
    if mount:
        model = onnx.load(out)
        entry = model.metadata_props.add()
        entry.key, entry.value = "radar_odom.mount_yaw_rad", repr(math.radians(mount))
        onnx.save(model, out)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default="cart-0.4", help="shipped name or checkpoint (default: %(default)s)")
    ap.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS),
                    help="hpH, bB, rR joined by +, e.g. r1+hp12 (+mD: a mount yaw of D°) (default: %(default)s)")
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {PARTS} (default: all)")
    args = ap.parse_args(argv)
    parts = [p for p in args.parts.split(",") if p]
    if bad := [p for p in parts if p not in PARTS]:
        ap.error(f"unknown part(s) {bad}; choose from {PARTS}")
    sys.path.insert(0, str(HERE))
    import eval_onnx
    import real_drive
    import yaw_precision

    folder = Path(tempfile.mkdtemp(prefix="band-limits-"))
    models = []
    for name in args.variants:
        print(f"exporting {args.checkpoint} {name} …", flush=True)
        models.append(str(export_variant(args.checkpoint, name, folder)))
    if "curves" in parts:
        yaw_precision.main(["--models", *models, "--parts", "curves"])
    if "real" in parts:
        yaw_precision.main(["--models", *models, "--parts", "radiate,oxford"])
        real_drive.main(["--models", *models, "--no-classical", "--no-kiss", "--no-deskew", "--stretch", "200:"])
    if "sim" in parts:
        eval_onnx.main([*models, "--seeds", "5000", "-o", str(folder / "sim.json")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
