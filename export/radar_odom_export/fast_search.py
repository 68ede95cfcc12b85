"""Fast rotation search for the stream step: coarse-to-fine yaw, factored matmul DFT.

`MaskedCorrelator.stream_step` scores every yaw candidate (the paper's ±15° at 0.5°: K = 61)
at every translation, which costs K rotations and K forward DFTs of W×W images per sweep.
`FastStreamStep` computes the same kind of volume on a few data-chosen rotations, faster:

1. **Coarse yaw** (`CoarseYawSelector`). Both images are reduced to ``W/f`` px by cropping their
   spectra to the low frequencies (an ideal low-pass; the previous sweep's spectrum is the stream
   state, the current one is computed for the new state anyway). The current low-res image is
   rotated by every ``stride``-th yaw candidate and correlated with the previous one over the
   whole translation window. The yaw whose best translation scores highest *relative to the
   rotated image's norm* is kept (ArgMax): interpolation blurs every rotation but the identity,
   and without the normalisation the energy it removes biases the pick towards yaw 0. With a
   stride above 1 the pick is moved to the fine step nearest the parabola through its score and
   its two neighbours' (`sub_step_offset`), so the band below is centred on the peak.
2. **Fine band** (`FastStreamStep`). The ``2b + 1`` consecutive candidates centred on that yaw
   (shifted, never truncated, to stay inside ±range) are evaluated at full resolution over the
   whole translation window, and so is yaw 0 (with the exact identity its spectrum is the new
   state's: no extra rotation or DFT; with the resampled one, one more round trip and DFT):
   driving straight is the common case, and the rare coarse pick that strays (1 of 956
   held-out steps at 0.4 m/px) then still finds the straight-ahead match.
3. **Soft-argmax over the evaluated yaws** (paper eq. 3): pose and covariance from the band's
   and yaw 0's candidates. Candidates outside get no weight, so **the covariance's yaw extent is
   limited to the band (and yaw 0)**, ``2b + 1`` steps wide. With a band covering every candidate
   (and ``rotation="bilinear"``) the step equals the exhaustive one (tests/test_fast_search.py).

**Rotation** (`PolarRotator`). onnxruntime's ``GridSample`` runs on one thread at ~20 ns per
sample, slower than the DFTs it feeds. Rotation about the centre is a shift along azimuth in
polar coordinates, so the image is resampled once onto a polar grid (the profile's
``rotation_kernel``: cubic onto one row per yaw step and one radius per pixel, or bilinear onto
two rows per yaw step and a radius every 0.5 px; `correlation.POLAR_GRIDS`), rolled by whole rows
for each candidate and resampled back (bilinear) with one table shared by every candidate; both
resamplings are ``GatherElements`` with constant tables computed in the graph (folded by
onnxruntime at session start). The first one writes the polar grid
already wrapped and zero-padded, and the band (consecutive yaws) reads one block of whole rows
of it (a ``Gather`` whose start is the only data-dependent index), so the second resampling's
tables are constant too, and no rolled copies are made (3.5× less gather time than K rolled
copies, whose random reads missed the cache). Yaw 0 follows ``profile.rotation_identity``, as
the exhaustive step's `Rotator` does: the image itself ("exact") or the same round trip as every
other yaw ("resampled"). ``rotation="bilinear"`` keeps ``grid_sample`` (exact identity only).

**Factored DFT** (`FactoredSpectrum`). A matmul DFT of W points costs W² per transform (the
export cannot use ``DFT`` nodes). With ``W = P·Q`` the four-step (Cooley–Tukey) factorisation
does a P-point then a Q-point DFT with twiddle factors between them: per 2-D real transform
four matmuls of about ``(6P + 6Q)·W²`` multiply-adds instead of ``3·W³`` (9× fewer at 512 px).
Each stage keeps real and imaginary parts next to the contracted axis, so one real matmul with
2×2-block matrices does a complex stage, and the twiddles are folded into the second stage's
matrices (one small matrix per first-stage frequency: a batched matmul). The spectrum comes out
in a permuted order (`natural_rows`, `natural_cols`) that the windowed inverse
(`WindowedInverse`) uses as it is; only the stream state is converted to and from the natural
half-spectrum layout of `MaskedCorrelator` ([B, 2, W, W//2 + 1]), so states are
interchangeable with the exhaustive step's.

The graph has static shapes (the sequence form's sweep count aside) and uses MatMul,
GatherElements, Gather, ArgMax, elementwise and shape ops: no ``DFT``/``STFT`` node, no complex
tensor. This module builds the step;
`onnx_export.export_fast` writes it (the file contract of the exhaustive export, stream form, plus
``radar_odom.search`` metadata); `FastSequenceStep` runs the same match on every consecutive pair
of T sweeps at once (`onnx_export.export_sequence`, the offline batch form). The DFT matrices live
in `dft`, the rotation grids in `correlation`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from radar_odom.profiles import GridProfile

from .correlation import polar_rotator, rotate_images, rotation_grids
from .dft import FactoredSpectrum, LowResImage, WindowedInverse
from .softargmax import candidate_weights, parabolic_peak, peak_window, pose_window, windowed_weights

ROTATIONS = ("polar", "bilinear")
NO_WEIGHT = -1e30  # a volume entry that softmax(β·C) weighs 0 for any β > 0


# ============================================================================ settings
@dataclass(frozen=True)
class FastSearchSettings:
    """How `FastStreamStep` searches yaw; all counts are in the profile's rotation steps.

    Attributes:
        coarse_factor: the coarse stage runs on ``W / coarse_factor`` px images (W must divide).
        coarse_stride: it scores every ``coarse_stride``-th yaw candidate (1 = all of them).
        band_half_width: b; the fine stage evaluates the ``2b + 1`` candidates around the
            coarse yaw at full resolution. ``2b + 1 >= K`` evaluates every candidate
            (the exhaustive search; the coarse stage is skipped).
        rotation: ``"polar"`` (`PolarRotator`: fast) or ``"bilinear"`` (``grid_sample``, the
            exhaustive step's own rotation: slow in onnxruntime, exact for comparisons).
    """

    coarse_factor: int = 4
    coarse_stride: int = 1
    band_half_width: int = 2
    rotation: str = "polar"

    def __post_init__(self):
        if self.coarse_factor < 1 or self.coarse_stride < 1 or self.band_half_width < 0:
            raise ValueError(f"{self}: coarse_factor and coarse_stride must be >= 1 and "
                             "band_half_width >= 0")
        if self.rotation not in ROTATIONS:
            raise ValueError(f"rotation={self.rotation!r}; choose one of {ROTATIONS}")

    def band_size(self, profile: GridProfile) -> int:
        """Rotations evaluated at full resolution (never more than the profile has)."""
        return min(2 * self.band_half_width + 1, profile.num_rotations)

    def is_exhaustive(self, profile: GridProfile) -> bool:
        return 2 * self.band_half_width + 1 >= profile.num_rotations

    def label(self) -> str:
        """Short name for tables, e.g. ``c4s1b2``."""
        tag = "" if self.rotation == "polar" else "-bilinear"
        return f"c{self.coarse_factor}s{self.coarse_stride}b{self.band_half_width}{tag}"


# Chosen per image width from measurements on held-out simulated drives and in onnxruntime
# (benchmarks/speed_accuracy.py): the coarse stage on a 64 px grid (every 2nd yaw where that
# measured as accurate), then a band of ±2 steps (±1°) at full resolution.
# A band of ±1 step is faster but puts the true yaw at the band's edge whenever the coarse pick
# is one step off, which biases the soft-argmax (4 held-out drives at 0.4 m/px: 0.0027 deg/m
# against 0.0003 exhaustive); ±2 steps matched the exhaustive search at every resolution.
# At 256 px the coarse stage scores every 3rd yaw (issue 43): the parabola through the best coarse
# score and its neighbours centres the ±2 band as well as every 2nd did (the same poses on 80
# simulated sweeps, the scorecard no worse: docs/scorecard.md) for two thirds of the coarse rotations
# (the graph 0.88x; docs/latency.md, "Half the step"); every 6th since issue 52: the shipped cart-0.4 re-exported
# so held every scorecard row on two fresh runs at 0.95-0.99 of the step (docs/scorecard.md; docs/latency.md,
# "Speed-accuracy frontier").
DEFAULT_SETTINGS = {
    128: FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=2),
    256: FastSearchSettings(coarse_factor=4, coarse_stride=6, band_half_width=2),
    512: FastSearchSettings(coarse_factor=8, coarse_stride=1, band_half_width=2),
}


def default_settings(profile: GridProfile) -> FastSearchSettings:
    """The settings used for ``profile`` when none are given (keyed by the image width)."""
    if profile.width_px in DEFAULT_SETTINGS:
        return DEFAULT_SETTINGS[profile.width_px]
    factor = 1
    while profile.width_px // (factor * 2) >= 64 and profile.width_px % (factor * 2) == 0:
        factor *= 2
    return FastSearchSettings(coarse_factor=factor, coarse_stride=1, band_half_width=2)


# ============================================================================ coarse yaw
def crop_spectrum(state: torch.Tensor, width_px: int, low_px: int) -> torch.Tensor:
    """Natural half spectrum [..., 2, W, W//2+1] → that of the ``low_px`` image [..., 2, w, w//2+1].

    Keeps the frequencies below the low-res Nyquist (an ideal low-pass) and zeroes the Nyquist
    row and column, which have no unambiguous source. The values are those of the W-point DFT,
    i.e. ``(W/w)²`` times the low-res image's own spectrum; only score ranks are used.
    """
    half = low_px // 2
    rows = torch.cat([torch.arange(half), torch.arange(width_px - half, width_px)])
    t = state[..., : half + 1].index_select(-2, rows.to(state.device))
    keep = torch.ones(low_px, half + 1, dtype=state.dtype, device=state.device)
    keep[half, :] = 0.0
    keep[:, half] = 0.0
    return t * keep


def sub_step_offset(scores: torch.Tensor, best: torch.Tensor, stride: int) -> torch.Tensor:
    """int64[B]: fine yaw steps from the best coarse yaw to the peak of a parabola through its score
    and its two neighbours' (``scores`` [B, Kc] over coarse yaws ``stride`` fine steps apart, ``best``
    int64[B] the argmax), rounded to a whole step, within ±stride/2; 0 where the best is at the
    list's end or the parabola does not curve down."""
    kc = scores.shape[1]
    lo = torch.gather(scores, 1, (best - 1).clamp(0, kc - 1).unsqueeze(1)).squeeze(1)
    mid = torch.gather(scores, 1, best.unsqueeze(1)).squeeze(1)
    hi = torch.gather(scores, 1, (best + 1).clamp(0, kc - 1).unsqueeze(1)).squeeze(1)
    den = lo - 2.0 * mid + hi
    ok = (best > 0) & (best < kc - 1) & (den < 0)
    safe = torch.where(ok, den, -torch.ones_like(den))
    frac = torch.where(ok, (0.5 * (lo - hi) / safe).clamp(-0.5, 0.5), torch.zeros_like(den))
    return torch.round(frac * stride).to(torch.int64)


class CoarseYawSelector(nn.Module):
    """Index (into ``profile.rotations_rad``) of the yaw that a low-res search scores best.

    Input: the previous and current sweeps' natural half spectra (states) [B, 2, W, W//2+1];
    output int64[B]. See the module docstring, step 1.
    """

    def __init__(self, profile: GridProfile, settings: FastSearchSettings):
        super().__init__()
        w, f = profile.width_px, settings.coarse_factor
        if w % f or (w // f) < 8:
            raise ValueError(f"coarse_factor {f} does not divide width {w} into >= 8 px images")
        self.width_px, self.low_px = w, w // f
        k = profile.num_rotations
        centre = k // 2
        s = settings.coarse_stride
        idx = sorted({*range(centre, -1, -s), *range(centre, k, s)})  # symmetric, holds yaw 0
        self.register_buffer("indices", torch.tensor(idx, dtype=torch.int64), persistent=False)
        self.centre = centre
        self.stride = s
        self.index_list = idx
        yaws = torch.tensor(profile.rotations_rad, dtype=torch.float64)[idx]
        self.register_buffer("yaws", yaws.to(torch.float32), persistent=False)
        self.rotator = (None if settings.rotation == "bilinear" else
                        polar_rotator(self.low_px, profile.rotation_step_rad, (self.low_px - 1) / 2, centre,
                                      profile.rotation_kernel))
        self.image = LowResImage(self.low_px)
        self.spectrum = FactoredSpectrum(self.low_px)
        self.inverse = WindowedInverse(self.low_px, max(1, math.ceil(profile.translation_cells / f)))

    def forward(self, prev_state: torch.Tensor, cur_state: torch.Tensor) -> torch.Tensor:
        prev = self.spectrum.from_natural(crop_spectrum(prev_state, self.width_px, self.low_px))
        cur = self.image(crop_spectrum(cur_state, self.width_px, self.low_px))  # [B, w, w]
        if self.rotator is None:
            rotated = rotate_images(cur, rotation_grids(self.yaws, self.low_px))
        else:
            rotated = self.rotator.rotate_constant(cur, [i - self.centre for i in self.index_list])
        volume = self.inverse(prev, self.spectrum(rotated))  # [B, Kc, n, n]
        # Normalised by each rotated image's norm: interpolation blurs every rotation but the
        # identity, and the energy it removes would otherwise pull the pick towards yaw 0.
        norm = torch.sqrt((rotated * rotated).flatten(2).sum(dim=-1) + 1e-12)
        scores = volume.flatten(2).amax(dim=-1) / norm  # [B, Kc]
        best = scores.argmax(dim=-1)
        if self.stride == 1:
            return self.indices[best]
        # Between two coarse yaws (stride steps apart) the peak can sit anywhere: a band centred on
        # the nearer coarse yaw would put a peak half-way at its edge, where the read-out has no
        # neighbour to refine with (a 0.6 °/sweep turn read as exactly 0.000 with a band from 0 to
        # 2° in 1°-stride coarse picks). A parabola through the best coarse score and its two
        # neighbours places the peak to within a fine step; the band is centred on that step.
        return self.indices[best] + sub_step_offset(scores, best, self.stride)


# ============================================================================ the step
class FastStreamStep(nn.Module):
    """``(cur, prev_state) → (pose, covariance, new_state)`` like `MaskedCorrelator.stream_step`.

    Same inputs, outputs and state format (single mode; the state is the previous masked
    sweep's natural half spectrum [B, 2, W, W//2 + 1]), so the two are interchangeable in a
    stream. The search is the module docstring's: a coarse yaw, then a band of ``2b + 1`` full-
    resolution yaws and yaw 0 over the whole translation window, soft-argmax over those.

    Args:
        model: a single-mode `MaskedCorrelator` (its masker, polar mapping and β are used).
        settings: `FastSearchSettings`; default `default_settings(model.profile)`.
    """

    def __init__(self, model, settings: FastSearchSettings | None = None):
        super().__init__()
        if getattr(model, "dual", False):
            raise ValueError("FastStreamStep needs a single-mode model: in dual mode the state is "
                             "the previous sweep and both masks are predicted together")
        p = model.profile
        self.model = model
        self.settings = settings or default_settings(p)
        self.band = self.settings.band_size(p)
        self.exhaustive = self.settings.is_exhaustive(p)
        self.num_rotations = p.num_rotations
        self.width_px = p.width_px
        self.spectrum = FactoredSpectrum(p.width_px)
        self.inverse = WindowedInverse(p.width_px, p.translation_cells)
        self.selector = None if self.exhaustive else CoarseYawSelector(p, self.settings)
        # features are zero beyond the support disc (model.support_disc): rotate only that
        disc_px = (p.width_px - 1) / 2 - p.translation_cells
        self.rotator = (None if self.settings.rotation == "bilinear" else
                        polar_rotator(p.width_px, p.rotation_step_rad, disc_px, p.num_rotations // 2,
                                      p.rotation_kernel))
        self.exact_identity = p.rotation_identity == "exact"
        if self.rotator is None and not self.exact_identity:
            raise ValueError(f"profile {p.name!r} scores yaw 0 resampled (rotation_identity="
                             "'resampled'), which only the polar rotation does; use rotation='polar'")
        self.register_buffer("yaw_table", torch.tensor(p.rotations_rad, dtype=torch.float64)
                             .to(torch.float32), persistent=False)
        offsets = torch.arange(-p.translation_cells, p.translation_cells + 1, dtype=torch.float64)
        self.register_buffer("offsets_m", (offsets * p.resolution_m).to(torch.float32), persistent=False)

    @property
    def profile(self) -> GridProfile:
        return self.model.profile

    def band_indices(self, prev_state: torch.Tensor, cur_state: torch.Tensor) -> torch.Tensor:
        """int64[B, 2b+1]: the yaw candidates evaluated at full resolution."""
        steps = torch.arange(self.band, device=prev_state.device)
        if self.exhaustive:
            return steps.unsqueeze(0).expand(prev_state.shape[0], self.band)
        centre = self.selector(prev_state, cur_state)
        low = (centre - self.band // 2).clamp(0, self.num_rotations - self.band)
        return low.unsqueeze(1) + steps

    def forward(self, cur: torch.Tensor, prev_state: torch.Tensor, cur_mask=None):
        features = self.model.sweep_features(cur, cur_mask)  # [B, W, W], support disc cut
        spec = self.spectrum(features)
        new_state = self.spectrum.to_natural(spec)
        pose, cov = self.match(self.spectrum.from_natural(prev_state), prev_state, features, spec, new_state)
        return pose, cov, new_state

    def match(self, prev_spec: torch.Tensor, prev_state: torch.Tensor, features: torch.Tensor,
              spec: torch.Tensor, new_state: torch.Tensor):
        """(pose [B, 3], covariance [B, 3, 3]) of each current sweep in its previous one's frame.

        The previous sweeps as their spectra in both layouts (``prev_spec``: the factored
        DFT's order, ``prev_state``: natural, the stream state), the current ones as their
        features [B, W, W], factored spectra and natural spectra; batch items are independent
        pairs (`forward`: one stream step; `FastSequenceStep`: consecutive sweeps of a batch).
        """
        indices = self.band_indices(prev_state, new_state)  # [B, Kb]
        # Yaw 0 is scored as well: driving straight is the common case, and a coarse pick that
        # strays (rare, at ~0.1 % of held-out steps) then still finds the straight-ahead match.
        # With the exact identity its spectrum is the one already computed for the new state (no
        # extra rotation or DFT); with the resampled one it is the polar round trip at shift 0,
        # from the band's polar grid, and one more DFT. When the band holds yaw 0 already, the
        # extra slice gets no weight (it would count twice).
        zero = torch.full_like(indices[:, :1], self.num_rotations // 2)
        has_zero = (indices == zero).any(dim=1, keepdim=True)  # [B, 1]
        if self.exact_identity:
            spectra = torch.cat([self.spectrum(self.rotate(features, indices)), spec.unsqueeze(1)], dim=1)
        else:
            spectra = self.spectrum(self.rotate(features, indices, with_zero=True))
        volume = self.inverse(prev_spec, spectra)  # [B, Kb + 1, N, N]
        drop = torch.cat([torch.zeros_like(indices, dtype=torch.bool), has_zero], dim=1)
        volume = volume.masked_fill(drop[:, :, None, None], NO_WEIGHT)
        return self.soft_argmax(volume, self.yaw_table[torch.cat([indices, zero], dim=1)])

    def rotate(self, features: torch.Tensor, indices: torch.Tensor, with_zero: bool = False) -> torch.Tensor:
        """features [B, W, W] rotated by the yaw candidates ``indices`` int64[B, Kb] → [B, Kb, W, W]
        (``with_zero``, resampled identity only: [B, Kb + 1, W, W], the last slice yaw 0).

        ``indices`` must be consecutive in each row (a band, as `band_indices` gives): the polar
        rotation reads them as one block (`PolarRotator.rotate_band`)."""
        if self.rotator is None:
            b, k = indices.shape  # one set of yaws per batch item
            grids = rotation_grids(self.yaw_table[indices].reshape(-1), self.width_px)
            return rotate_images(features, grids.reshape(b, k, *grids.shape[1:]))
        shifts = indices - self.num_rotations // 2
        # the band is consecutive (`band_indices`): one block of the polar grid, constant tables
        rotated = self.rotator.rotate_band(features, shifts[:, -1], shifts.shape[1], with_zero=with_zero)
        if not self.exact_identity:
            return rotated  # every yaw through the same round trip (GridProfile.rotation_identity)
        # yaw 0 is the image itself, exactly as in the exhaustive step (`Rotator`)
        return torch.where((shifts == 0)[:, :, None, None], features.unsqueeze(1), rotated)

    def soft_argmax(self, volume: torch.Tensor, yaws: torch.Tensor):
        """Paper eq. 3 over the evaluated yaws: volume [B, K', N, N], yaws [B, K'] → pose, covariance."""
        return search_soft_argmax(self.model, self.offsets_m, volume, yaws)


class FastSequenceStep(nn.Module):
    """``sweeps [T, ...] → (poses [T − 1, 3], covariances [T − 1, 3, 3])``: every consecutive pair
    of a batch of sweeps, matched as `FastStreamStep` matches a stream's (same numbers).

    The offline form (``radar_odom.odometry.batch``): T sweeps in one call, each masked and transformed
    once (as in a stream), all T − 1 pairs searched together, so onnxruntime runs a few large
    operators instead of T − 1 small steps. Pose k is sweep k + 1 in sweep k's frame.
    """

    def __init__(self, step: FastStreamStep):
        super().__init__()
        self.step = step

    @property
    def profile(self) -> GridProfile:
        return self.step.profile

    def forward(self, sweeps: torch.Tensor):
        s = self.step
        features = s.model.sweep_features(sweeps)  # [T, W, W]
        spec = s.spectrum(features)
        natural = s.spectrum.to_natural(spec)
        return s.match(spec[:-1], natural[:-1], features[1:], spec[1:], natural[1:])


def search_soft_argmax(model, offsets_m: torch.Tensor, volume: torch.Tensor, yaws: torch.Tensor):
    """Paper eq. 3 over the evaluated yaws of ``model.profile``: volume [B, K', N, N] over the
    translations ``offsets_m`` [N] (both axes) and yaws [B, K'] → (pose [B, 3], covariance
    [B, 3, 3], `MaskedCorrelator.covariance_from_moment` of the ``beta_cov`` moment)."""
    p = model.profile
    if p.pose_estimator == "parabolic":  # as `softargmax.read_pose`, on the band's yaws
        pose = parabolic_peak(volume, offsets_m, offsets_m, yaws, p.rotation_step_rad)
    else:
        window = pose_window(p)
        mask = None if window is None else peak_window(volume, offsets_m, offsets_m, yaws, *window)
        pose, _ = band_moments(windowed_weights(volume, p.beta_pose, mask), offsets_m, yaws)
    _, cov = band_moments(candidate_weights(volume, p.beta_cov).reshape(volume.shape), offsets_m, yaws)
    return pose, model.covariance_from_moment(cov)


def band_moments(weights: torch.Tensor, offsets_m: torch.Tensor, yaws: torch.Tensor):
    """Mean [B, 3] and covariance [B, 3, 3] of candidates (x_i, y_j, yaw_k) under weights
    [B, K, N, N] (summing to 1), with x_i = y_i = offsets_m[i] (N) and yaw_k = yaws[B, K].

    The same as `softargmax.weighted_mean` / `weighted_covariance` over the K·N·N candidate
    list, computed from the weights' marginals (the candidates form a grid), and centred
    before squaring, as there, to avoid float32 cancellation.
    """
    w_k = weights.sum(dim=(2, 3))  # [B, K]
    w_i = weights.sum(dim=(1, 3))  # [B, N] over x
    w_j = weights.sum(dim=(1, 2))  # [B, N] over y
    mean = torch.stack([w_i @ offsets_m, w_j @ offsets_m, (w_k * yaws).sum(dim=-1)], dim=-1)
    dx = offsets_m - mean[:, 0:1]  # [B, N]
    dy = offsets_m - mean[:, 1:2]
    da = yaws - mean[:, 2:3]  # [B, K]
    cxx = (w_i * dx * dx).sum(-1)
    cyy = (w_j * dy * dy).sum(-1)
    caa = (w_k * da * da).sum(-1)
    cxy = ((weights.sum(dim=1) @ dy.unsqueeze(-1)).squeeze(-1) * dx).sum(-1)  # Σ_ij w_ij dx_i dy_j
    cxa = ((weights.sum(dim=3) @ dx.unsqueeze(-1)).squeeze(-1) * da).sum(-1)  # Σ_ki w_ki dx_i da_k
    cya = ((weights.sum(dim=2) @ dy.unsqueeze(-1)).squeeze(-1) * da).sum(-1)
    cov = torch.stack([torch.stack([cxx, cxy, cxa], -1), torch.stack([cxy, cyy, cya], -1),
                       torch.stack([cxa, cya, caa], -1)], dim=-2)
    return mean, cov
