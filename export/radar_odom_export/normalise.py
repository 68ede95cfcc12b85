"""In-graph input normalisation: remove a radar's gain, offset and range-dependent noise floor.

Why. The correlation volume is a sum of products of two feature images, so it scales with the
square of the input's power, and the soft-argmax temperature ``β·C`` with it: a model tuned on
one radar's brightness gives a flat softmax (≈ zero motion) on a dimmer one. Navtech PNGs hold
*log* power (≈ 0.5 dB per count), so what legitimately differs between radars and set-ups is an
offset and a gain of the input and a range-dependent noise floor. Here (profile
``input_norm="floor-scale"``) every sweep ``Z`` ∈ [0, 1] is mapped, before the masker, to

    Z_n = min( relu(Z − floor(r)) / (scale + ε), clip )

* ``floor(r)``: a low robust quantile (``norm_floor_quantile``, default the median) of ``Z`` over
  azimuth on each of R rings about the sensor, linearly interpolated in range to every pixel —
  the noise floor, whatever its shape in range;
* ``scale``: a high quantile (``norm_scale_quantile``, default the 99th percentile) of
  ``relu(Z − floor)`` over the support disc (the pixels the features keep) — the sweep's gain;
* ``clip`` (``norm_clip``, default 4; 0 = none) keeps a few saturated pixels from dominating C.

For ``Z → a·Z + b`` (a > 0, nothing clipping at 0 or 1) the floor becomes ``a·floor + b``
exactly (bilinear samples and order statistics commute with an increasing affine map), so
``Z_n`` is unchanged up to ε = `EPS` relative to the scale. A constant or all-zero sweep gives
``Z_n ≡ 0``, never NaN. The normaliser has no weights and the input is data, so nothing is
detached: gradients reach the masker through ``Z_n`` (S = M(Z_n) ⊙ Z_n) as before.

Export: ``grid_sample`` (bilinear) samples the rings, ``TopK`` takes the order statistics
(no data-dependent shapes: k is fixed by the geometry), ``GatherElements`` interpolates the ring
profile back; the per-pixel ring coordinates are computed in the forward pass from a few
constants (like `fast_search.PolarRotator`'s tables), which the exporter or onnxruntime folds.
Opset 18, no DFT. Cost in onnxruntime (2 threads): ≈ 1 ms per sweep at 256 px, ≈ 8 ms at
512 px (mostly the scale's TopK over every pixel and the ring sampling).

Two geometries share the maths:

* `CartesianNormaliser` (``input_kind="cartesian"``): rings sampled on ``NORM_AZIMUTHS``
  azimuths every ``NORM_RING_STEP_PX`` pixels out to the support disc's radius.
* `PolarNormaliser` (``input_kind="polar"``): the model's input is the range-reduced polar
  sweep [B, A, B'], masked in polar, so the normalisation applies there, before the masker:
  each range bin is a ring (the quantile runs over all A azimuths, no resampling), and the
  scale is taken over the bins between the near-range blanking and the disc radius.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import INPUT_NORMS, GridProfile

NORM_AZIMUTHS = 64  # ring samples per ring: 64 give a stable median at ~1.5 % of the pixels' cost
NORM_RING_STEP_PX = 1.5  # ring spacing; the floor varies over tens of metres, far slower
EPS = 1e-6  # in input units (1/255 is one PNG count): only keeps 0/0 at 0 for a blank sweep


def rank_of_quantile(q: float, count: int) -> int:
    """The 1-based rank ``ceil(q·count)`` (clamped to 1..count) of the q-quantile's order statistic."""
    return int(min(max(math.ceil(q * count - 1e-9), 1), count))


def order_statistic(x: torch.Tensor, q: float, dim: int = -1) -> torch.Tensor:
    """The ``rank_of_quantile(q, n)``-th smallest value of ``x`` along ``dim`` (n = its size),
    that axis removed.

    Exact (no interpolation between ranks) and one ``TopK`` from whichever end is nearer, so
    a 99th percentile over 35 000 pixels keeps only 357 values.
    """
    n = x.shape[dim]
    k = rank_of_quantile(q, n)
    if k <= n - k + 1:
        return torch.topk(x, k, dim=dim, largest=False).values.select(dim, -1)
    return torch.topk(x, n - k + 1, dim=dim, largest=True).values.select(dim, -1)


def _interpolate_rings(profile: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """float[B, P]: ring profile float[B, R] read at ring coordinates u float[P] (ring index
    units), linearly; clamped to the first/last ring outside 0..R−1."""
    r = profile.shape[1]
    u = u.clamp(0.0, float(r - 1))
    lo = u.floor().clamp(max=float(r - 2))
    frac = u - lo
    # GatherElements (torch.gather): onnxruntime's Gather (index_select) is 2–3× slower here.
    # The ring-to-ring differences are taken first (R values, not one per pixel): the same
    # floats as b − a per pixel, one full-size op fewer
    lo = lo.to(torch.int64).unsqueeze(0).expand(profile.shape[0], -1)
    slope = profile[:, 1:] - profile[:, :-1]  # [B, R − 1]
    return torch.gather(profile, 1, lo) + frac * torch.gather(slope, 1, lo)


class CartesianNormaliser(nn.Module):
    """``Z`` float[..., W, W] in [0, 1] → ``Z_n`` float[..., W, W] ≥ 0 (module docstring).

    Args:
        width_px: W.
        radius_px: the support disc's radius (`model.support_disc`): rings reach it, and the
            scale is a quantile over the pixels inside it.
        floor_quantile, scale_quantile, clip: the profile's ``norm_*`` fields.
    """

    def __init__(self, width_px: int, radius_px: float, floor_quantile: float = 0.5,
                 scale_quantile: float = 0.99, clip: float = 4.0):
        super().__init__()
        self.width_px = int(width_px)
        self.radius_px = float(radius_px)
        self.floor_quantile = float(floor_quantile)
        self.scale_quantile = float(scale_quantile)
        self.clip = float(clip)
        self.num_rings = max(2, int(math.floor(self.radius_px / NORM_RING_STEP_PX)) + 1)
        c_w = (self.width_px - 1) / 2
        # ring sample (azimuth φ, radius ρ) at x = ρ·cos φ (up the rows), y = ρ·sin φ (columns);
        phi = 2 * np.pi * np.arange(NORM_AZIMUTHS) / NORM_AZIMUTHS
        rho = np.arange(self.num_rings) * NORM_RING_STEP_PX
        rows = c_w - rho[:, None] * np.cos(phi)[None, :]
        cols = c_w + rho[:, None] * np.sin(phi)[None, :]
        # grid_sample (align_corners=True) wants (column, row) normalised to ±1 at pixel centres;
        # [R, A, 2]: azimuth last, so the quantile's TopK runs along the innermost axis
        grid = np.stack([(cols - c_w) / c_w, (rows - c_w) / c_w], axis=-1)
        self.register_buffer("ring_grid", torch.from_numpy(grid.astype(np.float32))[None],
                             persistent=False)
        idx = np.arange(self.width_px) - c_w
        self.disc_pixels = int((idx[:, None] ** 2 + idx[None, :] ** 2 <= self.radius_px**2).sum())

    def _tables(self, dtype, device):
        """(ring coordinate float[W·W], disc float[W·W]) of every pixel, computed from aranges
        rather than stored: the exporter folds at most one W×W table (r²) into the file, and
        onnxruntime folds the rest at session start."""
        c_w = (self.width_px - 1) / 2
        d = torch.arange(self.width_px, dtype=dtype, device=device) - c_w
        r2 = (d[:, None] * d[:, None] + d[None, :] * d[None, :]).reshape(-1)
        disc = (r2 <= self.radius_px**2).to(dtype)
        return torch.sqrt(r2) / NORM_RING_STEP_PX, disc

    def ring_profile(self, z: torch.Tensor) -> torch.Tensor:
        """float[B, R]: the floor quantile over azimuth of each ring of z float[B, W, W]."""
        # the batch rides in the channel axis: one grid, one grid_sample call for all sweeps.
        # (`correlation.gather_lerp` would be ~0.3 ms faster in onnxruntime at 256 px, but it
        # rounds differently, and the shipped models' poses moved by up to 1e-4 m with it)
        rings = F.grid_sample(z.unsqueeze(0), self.ring_grid, mode="bilinear", padding_mode="zeros",
                              align_corners=True)[0]  # [B, R, A]
        return order_statistic(rings, self.floor_quantile, dim=-1)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        w = self.width_px
        flat = z.reshape(-1, w, w)
        u, disc = self._tables(z.dtype, z.device)
        floor = _interpolate_rings(self.ring_profile(flat), u)  # [B, W·W]
        x = torch.relu(flat.reshape(flat.shape[0], -1) - floor)
        # the q-quantile over the disc's pixels = the same-rank value over all pixels of x·disc:
        # the pixels outside add zeros, which never outrank a value ≥ 0 inside
        k_top = self.disc_pixels - rank_of_quantile(self.scale_quantile, self.disc_pixels) + 1
        scale = torch.topk(x * disc, k_top, dim=1).values[:, -1:]
        return _finish(x / (scale + EPS), self.clip).reshape(z.shape)


class PolarNormaliser(nn.Module):
    """Range-reduced polar sweeps float[..., A, B'] → ``Z_n`` of the same shape (module docstring).

    Args:
        keep: float[B'], 1 for the bins whose values enter the scale (beyond the near-range
            blanking, within the support disc's radius), 0 for the others.
        floor_quantile, scale_quantile, clip: the profile's ``norm_*`` fields.
    """

    def __init__(self, num_azimuths: int, keep: torch.Tensor, floor_quantile: float = 0.5,
                 scale_quantile: float = 0.99, clip: float = 4.0):
        super().__init__()
        self.num_azimuths = int(num_azimuths)
        self.floor_quantile = float(floor_quantile)
        self.scale_quantile = float(scale_quantile)
        self.clip = float(clip)
        keep = torch.as_tensor(keep, dtype=torch.float32)
        self.num_bins = int(keep.numel())
        self.kept = self.num_azimuths * max(int(keep.sum()), 1)
        self.register_buffer("keep", keep, persistent=False)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        flat = z.reshape(-1, self.num_azimuths, self.num_bins)
        floor = order_statistic(flat, self.floor_quantile, dim=1)  # [B, B']: each bin is a ring
        x = torch.relu(flat - floor.unsqueeze(1))
        k_top = self.kept - rank_of_quantile(self.scale_quantile, self.kept) + 1
        scale = torch.topk((x * self.keep).reshape(flat.shape[0], -1), k_top, dim=1).values[:, -1:]
        return _finish(x / (scale.unsqueeze(-1) + EPS), self.clip).reshape(z.shape)


def _finish(z_n: torch.Tensor, clip: float) -> torch.Tensor:
    return z_n.clamp(max=clip) if clip > 0 else z_n


def make_normaliser(profile: GridProfile, to_cartesian=None) -> nn.Module | None:
    """The normaliser ``profile.input_norm`` asks for (None for ``"none"``).

    ``to_cartesian``: the model's `model.PolarToCartesian` for the polar kind (its reduced
    range geometry places the near-range and disc limits on the bins).
    """
    if profile.input_norm not in INPUT_NORMS:
        raise ValueError(f"input_norm={profile.input_norm!r}; choose one of {INPUT_NORMS}")
    if profile.input_norm == "none":
        return None
    q = dict(floor_quantile=profile.norm_floor_quantile, scale_quantile=profile.norm_scale_quantile,
             clip=profile.norm_clip)
    radius_px = (profile.width_px - 1) / 2 - profile.translation_cells - 1  # = support_disc's
    if to_cartesian is None:
        return CartesianNormaliser(profile.width_px, radius_px, **q)
    centres = to_cartesian.offset_m + to_cartesian.reduced_rr * torch.arange(to_cartesian.num_bins,
                                                                            dtype=torch.float64)
    keep = (to_cartesian.near_keep.to(torch.float64) > 0) & (centres <= radius_px * profile.resolution_m)
    return PolarNormaliser(to_cartesian.num_azimuths, keep.to(torch.float32), **q)
