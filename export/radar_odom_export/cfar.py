"""A training-free mask: cell-averaging CFAR on the normalised sweep (``masking="cfar"``).

For a radar with no ground truth to train on, the classical detector: a cell is kept where its
normalised power ``Z_n`` (`normalise`) stands out from its neighbourhood and from the floor,

    M = σ((Z_n − α·mean_box(Z_n)) / s) · σ((Z_n − m) / s)

with ``mean_box`` the mean over a box of ``cfar_window_m`` (cells outside the image not counted),
``α = cfar_alpha``, ``m = cfar_min_level`` (normalised units: 1 is the sweep's 99th-percentile
return above the floor) and the soft width ``s = CFAR_SOFTNESS``. The sigmoids are steep
steps that stay continuous, so a value within float rounding of a threshold cannot flip a pixel
between torch and onnxruntime. On the Cartesian image the box is square; on the polar kind
(masked in polar) it runs along range only, like a radar's own CA-CFAR, since an azimuth
step spans very different distances at 3 m and at 50 m.

``Z_n`` does not change with the radar's gain and offset, so neither does the mask. Export:
``AveragePool`` (count_include_pad=0), ``Sigmoid`` and elementwise ops.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import GridProfile

CFAR_SOFTNESS = 0.02  # normalised units: 2 % of the sweep's scale from "off" to "on"


def odd_cells(length_m: float, cell_m: float) -> int:
    """The odd number of cells (≥ 1) nearest to ``length_m`` at ``cell_m`` per cell."""
    n = max(1, int(round(length_m / cell_m)))
    return n if n % 2 else n + 1


class CFARMask(nn.Module):
    """Normalised sweeps float[..., H, W] → masks in [0, 1] of the same shape.

    Args:
        window: (rows, columns) of the averaging box, odd.
        alpha, min_level: the thresholds (module docstring).
    """

    def __init__(self, window: tuple[int, int], alpha: float, min_level: float,
                 softness: float = CFAR_SOFTNESS):
        super().__init__()
        self.window = (int(window[0]), int(window[1]))
        if any(k < 1 or k % 2 == 0 for k in self.window):
            raise ValueError(f"CFAR window {self.window} must be odd and >= 1 cells")
        self.alpha = float(alpha)
        self.min_level = float(min_level)
        self.softness = float(softness)

    def local_mean(self, z: torch.Tensor) -> torch.Tensor:
        """float[..., H, W]: the box mean of z over the window (edges: the cells inside only)."""
        kh, kw = self.window
        x = z.reshape(-1, 1, *z.shape[-2:])
        mean = F.avg_pool2d(x, (kh, kw), stride=1, padding=(kh // 2, kw // 2), count_include_pad=False)
        return mean.reshape(z.shape)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        s = self.softness
        above_local = torch.sigmoid((z - self.alpha * self.local_mean(z)) / s)
        return above_local * torch.sigmoid((z - self.min_level) / s)


def make_cfar(profile: GridProfile, to_cartesian=None) -> CFARMask:
    """The CFAR mask of ``profile`` (``cfar_*`` fields) for its input kind."""
    if to_cartesian is None:
        k = odd_cells(profile.cfar_window_m, profile.resolution_m)
        window = (k, k)
    else:  # polar input [A, B']: along range only, in reduced bins
        window = (1, odd_cells(profile.cfar_window_m, to_cartesian.reduced_rr))
    return CFARMask(window, profile.cfar_alpha, profile.cfar_min_level)
