"""A left/right mirror-symmetric masker: the fix for the straight-road yaw bias (issue 41).

Every stage of the search after the masker is mirror-equivariant: reflect both sweeps left/right
(image columns reversed, y → −y) and the graph reads (x, −y, −yaw) — to float precision, with the
cubic polar rotation, the high-pass, the coarse pick and the parabolic read-out
(tests/test_yaw_bias.py). The learned U-Net is not: its 3×3 kernels are free to be handed, and its
masks of a forward move read a turn to one side (the shipped cart-0.4 on frozen straight sweeps:
−0.030 °/sweep, of which the handed masker −0.022; docs/yaw-precision.md, "Straight-road yaw bias").

A convolution whose kernels equal their own column flip commutes with the column flip of its
input; ReLU, the sigmoid, 1×1 convolutions, 2×2 max-pools and ×2 bilinear upsampling (half-pixel
centres) on even sizes, zero padding symmetric on both sides, and the masker's 2× average pool
all commute with it too. So a U-Net whose every kernel is left/right symmetric is
mirror-equivariant, and with it the whole graph: no yaw from the masker's handedness, at no
run-time cost (same graph, other weights).
"""
from __future__ import annotations

import torch
from torch import nn


def symmetrise_left_right_(module: nn.Module) -> int:
    """Make every 2-D convolution (and transposed convolution) in ``module`` left/right symmetric, in
    place: each kernel replaced by the mean of itself and its column flip (the nearest symmetric
    kernel in the least-squares sense). Returns the number of layers changed; biases are kept."""
    changed = 0
    with torch.no_grad():
        for layer in module.modules():
            if isinstance(layer, (nn.Conv2d, nn.ConvTranspose2d)):
                w = layer.weight
                w.copy_(0.5 * (w + w.flip(-1)))
                changed += 1
    return changed


class _LeftRightMean(nn.Module):
    """Parametrization W -> (W + W.flip(-1)) / 2: the kernel the layer uses is always left/right
    symmetric, whatever the optimiser does to the stored one (its gradient is the symmetric part)."""

    def forward(self, weight: torch.Tensor) -> torch.Tensor:
        return 0.5 * (weight + weight.flip(-1))


def constrain_left_right_(module: nn.Module) -> int:
    """Constrain every 2-D convolution (and transposed convolution) in ``module`` to left/right
    symmetric kernels for training (`torch.nn.utils.parametrize`), in place; returns the number of
    layers constrained. The stored kernels are symmetrised first, so the constrained weights start
    where the module was. `checkpoint.checkpoint_dict` saves the plain (symmetric) weights, so
    export and runtime see an ordinary U-Net."""
    from torch.nn.utils import parametrize

    symmetrise_left_right_(module)
    layers = [m for m in module.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))]
    for layer in layers:
        if not parametrize.is_parametrized(layer, "weight"):
            parametrize.register_parametrization(layer, "weight", _LeftRightMean())
    return len(layers)


def is_left_right_symmetric(module: nn.Module, atol: float = 0.0) -> bool:
    """Whether every 2-D convolution kernel in ``module`` equals its column flip (to ``atol``)."""
    return all(torch.allclose(layer.weight, layer.weight.flip(-1), rtol=0.0, atol=atol)
               for layer in module.modules() if isinstance(layer, (nn.Conv2d, nn.ConvTranspose2d)))


def mirror_symmetric_checkpoint(ckpt: dict) -> dict:
    """A checkpoint dictionary (`checkpoint.read_checkpoint_dict`) whose learned masker is made
    left/right symmetric (`symmetrise_left_right_`); profile, calibration and the rest unchanged,
    ``train["masker_symmetry"]`` says what was done. Raises ValueError for a model without a
    learned masker (raw and CFAR have nothing handed to remove)."""
    from .checkpoint import model_from_dict

    if ckpt.get("masking") != "learned":
        raise ValueError(f"masking={ckpt.get('masking')!r}: only a learned masker can be handed; "
                         "raw and CFAR masks are mirror-symmetric already")
    model = model_from_dict(ckpt)
    symmetrise_left_right_(model.masker)
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    train = dict(ckpt.get("train") or {})
    train["masker_symmetry"] = "left-right: every kernel averaged with its column flip (issue 41)"
    return {**ckpt, "state_dict": state, "train": train}


def mirror_averaged_checkpoint(ckpt: dict) -> dict:
    """A checkpoint dictionary whose masker's output is averaged over the left/right mirror
    (``profile["mask_mirror_average"] = True``: (M(x) + flip(M(flip(x)))) / 2, `MaskedCorrelator`):
    the graph becomes mirror-equivariant with the weights as they are (unlike `mirror_symmetric_checkpoint`,
    which averages the kernels and loses their antisymmetric part). Weights and calibration unchanged,
    ``train["masker_symmetry"]`` says what was done; the masks change scale, so recalibrate before
    shipping. Raises ValueError for a model without a learned masker."""
    from radar_odom.profiles import GridProfile

    if ckpt.get("masking") != "learned":
        raise ValueError(f"masking={ckpt.get('masking')!r}: only a learned masker can be handed; "
                         "raw and CFAR masks are mirror-symmetric already")
    profile = {**ckpt["profile"], "mask_mirror_average": True}
    GridProfile.from_dict(profile)  # refuses a profile the average does not apply to (polar input)
    train = dict(ckpt.get("train") or {})
    train["masker_symmetry"] = "left-right: the mask averaged with the mirrored mask of the mirror image (issue 41)"
    return {**ckpt, "profile": profile, "train": train}
