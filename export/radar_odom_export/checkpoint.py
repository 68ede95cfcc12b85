"""Checkpoints: plain dictionaries that ``torch.load(path, weights_only=True)`` can read.

Format ``radar-odom-checkpoint/1``::

    {"format": "radar-odom-checkpoint/1",
     "profile": asdict(GridProfile),          # the grid, both β, the U-Net size
     "masking": "learned" | "raw" | "cfar",   # "raw": mask ≡ 1, "cfar": classical mask; nothing trained
     "state_dict": {name: tensor},            # learnable weights only (may be empty)
     "train": {...},                          # how it was made: command, seeds, wall_s, ...
     "calibration": {...}}                    # optional: written by `radar-odom calibrate`

Only tensors, strings, numbers, lists and dicts: no pickled classes, so loading never runs
code. Buffers the model rebuilds from its profile (rotation grids, DFT matrices) are not
stored: they are non-persistent, and keeping the file to the weights keeps it small.
"""
from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path

import torch

from radar_odom.errors import RadarOdomError
from radar_odom.profiles import GridProfile

FORMAT = "radar-odom-checkpoint/1"
MASKINGS = ("learned", "raw", "cfar")


class CheckpointError(RadarOdomError, ValueError):
    """A file is not a radar-odom checkpoint (or one this version cannot read)."""


def checkpoint_dict(model, masking: str, train: dict | None = None, calibration: dict | None = None) -> dict:
    """The plain dictionary saved for ``model`` (a ``MaskedCorrelator``)."""
    if masking not in MASKINGS:
        raise ValueError(f"masking={masking!r}: checkpoints describe one of {MASKINGS}")
    state = {k: v.detach().cpu().clone() for k, v in _plain_state(model).items()}
    out = {
        "format": FORMAT,
        "profile": asdict(model.profile),
        "masking": masking,
        "state_dict": state,
        "train": _plain(train or {}),
    }
    if calibration is not None:
        out["calibration"] = _plain(calibration)
    return out


def _plain_state(model) -> dict:
    """``model.state_dict()`` with each parametrized weight (`symmetry.constrain_left_right_`
    during training) stored as the weight the layer uses, under its ordinary name: the checkpoint
    loads without the constraint. Built from the state, not by removing the parametrizations
    from a copy: a copy shares the parametrized class, and removing them there breaks the model."""
    out = {}
    for key, value in model.state_dict().items():
        head, sep, tail = key.partition("parametrizations.")
        if not sep:
            out[key] = value
        elif tail.endswith(".original"):  # "<layer>.parametrizations.<name>.original" -> "<layer>.<name>"
            name = tail[: -len(".original")]
            layer = model.get_submodule(head[:-1]) if head else model
            out[head + name] = getattr(layer, name).detach()
    return out


def save_checkpoint(path, model, masking: str, train: dict | None = None, calibration: dict | None = None) -> Path:
    """Write ``model`` as a checkpoint (atomically: temp file then rename)."""
    return write_checkpoint_dict(path, checkpoint_dict(model, masking, train, calibration))


def write_checkpoint_dict(path, ckpt: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save(ckpt, tmp)
    os.replace(tmp, path)
    return path


def read_checkpoint_dict(path) -> dict:
    """The checkpoint's dictionary, validated; `CheckpointError` for anything else.

    Loads with ``weights_only=True``: a file holding pickled objects (arbitrary code) is
    refused, never executed.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # UnpicklingError, zip errors, truncated files, ...
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        why = next(
            (ln for ln in lines if "Unsupported global" in ln or "WeightsUnpickler" in ln), lines[0] if lines else ""
        )
        raise CheckpointError(
            f"{path}: not a radar-odom checkpoint ({type(exc).__name__}: {why[:240]}); it was not loaded "
            "because radar-odom checkpoints hold only tensors and plain values (no pickled objects) — "
            "make one with `radar-odom train`"
        ) from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        got = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise CheckpointError(f"{path}: format is {got!r}, expected {FORMAT!r}; make one with `radar-odom train`")
    for key, kind in (("profile", dict), ("masking", str), ("state_dict", dict), ("train", dict)):
        if not isinstance(ckpt.get(key), kind):
            raise CheckpointError(f"{path}: field {key!r} is missing or not a {kind.__name__}")
    if ckpt["masking"] not in MASKINGS:
        raise CheckpointError(f"{path}: masking {ckpt['masking']!r} is not one of {MASKINGS}")
    bad = [k for k, v in ckpt["state_dict"].items() if not isinstance(v, torch.Tensor)]
    if bad:
        raise CheckpointError(f"{path}: state_dict entries {bad[:3]} are not tensors")
    try:
        GridProfile.from_dict(ckpt["profile"])
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: invalid profile: {exc}") from None
    return ckpt


def model_from_dict(ckpt: dict, dft: str = "fft", source: str = "checkpoint"):
    """Build the ``MaskedCorrelator`` a checkpoint dictionary describes, weights loaded."""
    from .model import MaskedCorrelator

    profile = GridProfile.from_dict(ckpt["profile"])
    model = MaskedCorrelator(profile, masking=ckpt["masking"], dft=dft)
    try:
        model.load_state_dict(ckpt["state_dict"], strict=True)
    except RuntimeError as exc:
        raise CheckpointError(
            f"{source}: weights do not fit a {ckpt['masking']} model on profile {profile.name!r}: "
            f"{str(exc).splitlines()[0][:300]}"
        ) from None
    model.eval()
    return model


def load_checkpoint(path, dft: str = "fft"):
    """``(model, meta)``: the model in eval mode and the checkpoint's other fields.

    ``meta`` has ``profile`` (a `GridProfile`), ``masking``, ``train`` and, when calibrated,
    ``calibration``. Raises `CheckpointError` for anything that is not a checkpoint.
    """
    ckpt = read_checkpoint_dict(path)
    model = model_from_dict(ckpt, dft=dft, source=str(path))
    meta = {k: v for k, v in ckpt.items() if k != "state_dict"}
    meta["profile"] = model.profile
    return model, meta


def _plain(obj):
    """Recursively convert to what ``weights_only`` loading accepts (no numpy scalars, tuples ok)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, str):
        return str(obj)  # str subclasses (torch.__version__) would need their class to load
    if isinstance(obj, bool) or obj is None:
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj)
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if hasattr(obj, "tolist"):  # numpy arrays and scalars -> nested lists / Python numbers
        return obj.tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"cannot store {type(obj).__name__} in a checkpoint; use plain values")


# ----------------------------------------------------------------------------- shipped checkpoints
SHIPPED_DIR = Path(__file__).resolve().parent / "checkpoints"


def shipped_checkpoint_names() -> list[str]:
    """Names of the checkpoints shipped with the package (those of the pretrained ONNX models)."""
    return sorted(p.stem for p in SHIPPED_DIR.glob("*.pt"))


def resolve_checkpoint(name_or_path) -> Path:
    """A checkpoint file: ``name_or_path`` itself when it exists, else the shipped checkpoint of
    that name (``"cart-0.4"`` or ``"cart-0.4.pt"``); `CheckpointError` naming both otherwise."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    stem = path.name[:-3] if path.name.endswith(".pt") else path.name
    if path.parent == Path(".") and stem in shipped_checkpoint_names():
        return SHIPPED_DIR / f"{stem}.pt"
    raise CheckpointError(
        f"{name_or_path}: no such checkpoint file, and not a shipped checkpoint name "
        f"({', '.join(shipped_checkpoint_names()) or 'none shipped'})"
    )


def provenance_command(argv) -> str:
    """The command line as a checkpoint records it, absolute paths cut to their file names (the
    checkpoint, and the model exported from it, must not carry build-machine paths)."""
    import os
    import shlex

    return "radar-odom " + " ".join(shlex.quote(os.path.basename(a) if os.path.isabs(a) else a) for a in argv)
