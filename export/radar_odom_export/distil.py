"""Distilling a narrower masker from a trained one (issue 43 "half the step", issue 41's yaw bias).

The masker is 37–41 % of cart-0.4's step (docs/latency.md, "Where the step's time goes"); every U-Net
level costs about the same FLOPs, and each scales with the square of the width, so a U-Net of half the
base width costs about a quarter. Rather than train the narrow U-Net through the pose search again (a CPU
budget of hours), the student learns to reproduce the shipped (teacher) masker's masks, which is a cheap
per-pixel regression: no correlation volume in the training step.

The target is the teacher's mask *mirror-averaged*::

    target(z) = (T(z) + flip(T(flip(z)))) / 2          flip: image columns reversed (y → −y)

the left/right mirror of `data.mirror_pair` and `symmetry`. The shipped cart-0.4 masker is handed (its
masks of a forward move read a turn to one side: docs/yaw-precision.md, "Straight-road yaw bias"); the
mirror average is the nearest unhanded mask, so the student learns the teacher's masks without their
handedness. (Unlike `symmetry.symmetrise_left_right_`, which averages the *kernels* and so changes
every layer's output, this averages the teacher's *output*.)

Loss: mean squared difference between the student's mask and the target, both on the masker's output
grid upsampled to the image (the masks the features use), plus optionally ``pose_weight`` × the
pose cross-entropy (`train.pose_cross_entropy`) of the student's correlation volume, so the student's
masks stay good for matching where the mask loss alone does not decide (`train.DistilObjective`).
"""
from __future__ import annotations

from dataclasses import asdict

import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import GridProfile

from .checkpoint import CheckpointError
from .model import mirror_averaged

# fields a student may differ from its teacher in: the U-Net's size, and the calibration (a student is
# calibrated again after training; its profile starts from the teacher's)
STUDENT_FIELDS = ("unet_base_channels", "unet_depth", "mask_downsample")
CALIBRATION_FIELDS = ("beta_cov", "cov_scale", "cov_floor_cells", "cov_floor_yaw_cells")
MASK_LOSS_TEXT = "mean[(student mask - (T(z) + flip(T(flip(z))))/2)^2], T the frozen teacher masker"


def mirror_columns(images: torch.Tensor) -> torch.Tensor:
    """Images [..., H, W] reflected left/right (columns reversed: y → −y, `data.mirror_pair`)."""
    return images.flip(-1)


@torch.no_grad()
def mirror_averaged_masks(teacher: nn.Module, z: torch.Tensor) -> torch.Tensor:
    """float[B, H, W]: the teacher's masks of the normalised sweeps z [B, H, W], averaged with the
    mirror image of its masks of the mirrored sweeps: an unhanded target (module docstring)."""
    return mirror_averaged(teacher._mask, z)


def student_profile(teacher: GridProfile, base_channels: int | None, depth: int | None,
                    mask_downsample: int | None = None) -> GridProfile:
    """The teacher's profile with the student's U-Net width / depth and the grid its masker runs on
    (``mask_downsample``: the masker on a grid that much coarser, its mask upsampled; None: the teacher's)."""
    changes = {}
    if base_channels:
        changes["unet_base_channels"] = int(base_channels)
    if depth:
        changes["unet_depth"] = int(depth)
    if mask_downsample:
        changes["mask_downsample"] = int(mask_downsample)
    return teacher.with_(**changes) if changes else teacher


def check_student(student: GridProfile, teacher: GridProfile) -> None:
    """`CheckpointError` unless the student's profile is the teacher's but for the U-Net size and the
    calibration: the masks are compared pixel for pixel, so grid, normalisation and mode must agree."""
    t, s = asdict(teacher), asdict(student)
    differ = [f for f in t if t[f] != s.get(f) and f not in STUDENT_FIELDS + CALIBRATION_FIELDS + ("name",)]
    if differ:
        raise CheckpointError(
            f"--distill-from: the teacher's profile {teacher.name!r} differs from the student's in "
            f"{', '.join(differ)}; a student may differ only in {', '.join(STUDENT_FIELDS)}"
        )


def load_teacher(path, device=None) -> nn.Module:
    """The teacher `MaskedCorrelator` of checkpoint ``path`` (a shipped name or a file), frozen, in eval
    mode; `CheckpointError` unless it has a learned single-mode masker."""
    from .checkpoint import load_checkpoint, resolve_checkpoint

    model, meta = load_checkpoint(resolve_checkpoint(path))
    if meta.get("masking") != "learned" or model.dual:
        raise CheckpointError(f"--distill-from {path}: needs a learned single-mode masker "
                              f"(it has masking={meta.get('masking')!r}, mode={model.profile.mode!r})")
    model.eval().requires_grad_(False)
    return model if device is None else model.to(device)


def mask_loss(student: nn.Module, teacher: nn.Module, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, masks): the mean squared difference between the student's masks of the normalised sweeps z
    [B, H, W] and the teacher's mirror-averaged ones, and the student's masks (for the features)."""
    masks = student._mask(z)
    return F.mse_loss(masks, mirror_averaged_masks(teacher, z)), masks
