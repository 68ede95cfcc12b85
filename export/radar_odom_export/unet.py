"""The masking network: the paper's U-Net (Sec. 5.2, appendix architecture figure).

Encoder: per level two 3×3 convolutions with ReLU, then a 2×2 max-pool that halves the size
and doubles the channels, ``base → base·2^depth`` (paper: 8 → 256 over 5 pools). Decoder:
bilinear upsampling ×2, concatenation with the encoder's skip at that level, two 3×3
convolutions with ReLU halving the channels. A final 1×1 convolution gives ``out_channels``
masks and a sigmoid keeps them in [0, 1]. Single mode is 1 → 1; dual mode stacks the previous
and current sweep as 2 input channels and predicts their 2 masks.

``base_channels`` and ``depth`` are configurable (a slimmer network runs faster on CPU); the
paper's is ``UNet(1, 1, base_channels=8, depth=5)``. Inputs whose sides are not multiples of
``2**depth`` (e.g. a 400-azimuth polar sweep) are zero-padded at the bottom/right and the
output is cropped back, so any static size works.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

HEAD_BIAS_INIT = -3.0


def _double_conv(in_ch: int, out_ch: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_ch, out_ch, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(out_ch, out_ch, 3, padding=1), nn.ReLU(inplace=True),
    )


class UNet(nn.Module):
    """float[B, in_channels, H, W] → masks float[B, out_channels, H, W] in [0, 1]."""

    def __init__(self, in_channels: int = 1, out_channels: int = 1, base_channels: int = 8,
                 depth: int = 5):
        super().__init__()
        if depth < 1 or base_channels < 1:
            raise ValueError(f"UNet needs depth >= 1 and base_channels >= 1, got depth={depth}, "
                             f"base_channels={base_channels}")
        self.depth = depth
        widths = [base_channels * 2**level for level in range(depth + 1)]
        self.down = nn.ModuleList(
            [_double_conv(in_channels, widths[0])]
            + [_double_conv(widths[lv - 1], widths[lv]) for lv in range(1, depth + 1)]
        )
        # decoder level lv takes the upsampled level lv+1 features plus the level-lv skip
        self.up = nn.ModuleList(
            [_double_conv(widths[lv + 1] + widths[lv], widths[lv]) for lv in range(depth)]
        )
        self.head = nn.Conv2d(widths[0], out_channels, 1)
        # Start with nearly closed masks (sigmoid(-3) ≈ 0.05). With half-open masks the
        # correlation scores of a whole sweep run into the thousands and softmax(β·C) at the
        # paper's β = 1 is a hard argmax with no gradient; small masks start the soft-argmax
        # soft, and training opens them where matching pays (the scale is the mask's to learn).
        nn.init.constant_(self.head.bias, HEAD_BIAS_INIT)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        height, width = x.shape[-2:]
        step = 2**self.depth
        pad_h, pad_w = -height % step, -width % step
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h))
        skips = []
        for level, block in enumerate(self.down):
            x = block(x if level == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        x = skips.pop()
        for level in reversed(range(self.depth)):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = self.up[level](torch.cat([x, skips[level]], dim=1))
        return torch.sigmoid(self.head(x))[..., :height, :width]
