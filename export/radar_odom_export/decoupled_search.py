"""Decoupled rotation search for the stream step (Fast-MbyM, Weston et al., ICRA 2022).

The coarse-to-fine search (`fast_search`) still rotates the current sweep once per yaw
candidate of its band and correlates each. The decoupled search uses that the magnitude of the
Fourier transform does not depend on translation: rotating an image rotates its magnitude
spectrum by the same angle, whatever the shift. So

1. **Rotation** (`RingCorrelation`). The previous and current masked sweeps' magnitude spectra
   (``|F|``, from their natural half spectra: the previous one is the stream state, the current
   one is the new state, computed anyway) are resampled to ``A`` angles × ``R`` rings
   (compressed, ``|F|^½`` or ``log |F|``, they measured worse on validation drives: median yaw
   error 0.081° and 0.175° against 0.076° with 32 rings). Angles cover 180° only
   (``|F(−k)| = |F(k)|`` for real images) in steps of the profile's yaw step over
   ``angle_oversample``; the rings run from ``radius_min`` to
   ``radius_max`` of the Nyquist radius ``W/2`` (the DC region is skipped: its energy is
   isotropic). Resampling is bilinear ``GatherElements`` with constant tables (``A·R`` samples
   per image). Each ring's mean is removed, and the circular correlation along the angle axis,
   summed over rings, is computed as a real DFT along angles (one matmul per image), a
   cross-power summed over rings, and an inverse at the ``2S + 1`` shifts of the ±yaw range only
   (one small matmul). The yaw is the best shift refined by a parabola through it and its two
   neighbours (sub-bin read-out); its variance is the second moment of
   ``softmax(beta_yaw · ĉ)`` over the shifts, ĉ the correlation normalised to a cosine
   similarity in [−1, 1] (so ``beta_yaw`` does not depend on the sweep's power).
2. **Translation** (`CropRotation`). The current features are rotated once, by that
   (continuous) yaw: bilinear ``GatherElements`` whose tables are computed in the graph from the
   yaw (the only data-dependent index), on the central ``W − 2n`` square only (features are zero
   outside the support disc, which that square holds), then zero-padded back. One factored DFT
   (`dft.FactoredSpectrum`) and one windowed inverse (`dft.WindowedInverse`) give the N×N
   translation volume at that yaw.
3. **Pose and covariance**: x, y by the profile's soft-argmax over the translation volume
   (`fast_search.search_soft_argmax`, paper eq. 3, one yaw); yaw from stage 1. The 3×3
   covariance: the x/y block from the translation softmax (``beta_cov``), the yaw variance from
   stage 1, no x/y–yaw cross terms (the stages are independent by construction), then the
   profile's ``cov_scale`` and floor as for every search.

Cost per sweep beyond the masker (0.4 m/px, W = 256, n = 20, defaults A = 360, R = 64), counted
from the code: the sweep's own factored DFT and the state's layout changes (as in the fast
search), 2·A·R = 46 k bilinear samples of the magnitudes, two angular DFTs of R×A by A×(A + 2)
(16.7 M multiply-adds), one rotation of (W − 2n)² = 47 k samples, one more factored DFT
(12.6 M) and one windowed inverse (7 M): about 49 M multiply-adds and 93 k bilinear samples.
The fast search (cart-0.4's settings) does about 147 M and 970 k (README: decoupled search).

Not done here, measured and dropped: refining the ring yaw with a few translation correlations
at nearby yaws. On 64 px images it was pulled towards yaw 0 (bilinear rotation blurs the less
the closer to 0; by half a degree on validation drives turning 0.9° per sweep), and with both
images turned by a common 8° to equalise the blur its median error (0.12–0.14°) was worse than
the ring yaw's alone (0.065–0.09°, two validation seeds).

The state is the previous masked sweep's natural half spectrum [B, 2, W, W//2 + 1], as in
`FastStreamStep` and `MaskedCorrelator.stream_step`: states are interchangeable. The graph uses
MatMul, GatherElements, ArgMax, elementwise and shape ops: no ``DFT``/``STFT`` node, no
``torch.fft``. Everything is differentiable in the sweep (the argmax only picks where the
parabola is read), so a masker can be trained through both stages (`DecoupledPairStep`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import GridProfile

from .correlation import bilinear_table, gather_lerp
from .dft import FactoredSpectrum, WindowedInverse, float32_buffer, forward_column_matrix, half_spectrum_inverse_matrix
from .fast_search import search_soft_argmax


# ============================================================================ settings
@dataclass(frozen=True)
class DecoupledSettings:
    """How `DecoupledStreamStep` finds the yaw from the magnitude spectra.

    Attributes:
        angle_oversample: angular bins per yaw step (``profile.rotation_step_rad``); the bins
            cover 180°, so A = ``oversample · π / step`` (360 at 0.5°).
        radii: R, rings resampled between ``radius_min`` and ``radius_max``.
        radius_min, radius_max: the ring band as fractions of the Nyquist radius W/2
            (0 < min < max ≤ 0.98).
        beta_yaw: softmax temperature on the normalised ring correlation (cosine similarity in
            [−1, 1]) for the yaw variance only; the yaw itself is the parabolic peak.
    """

    angle_oversample: int = 1
    radii: int = 64
    radius_min: float = 0.1
    radius_max: float = 0.6
    # Not calibrated. 4000 gave the yaw's own d² a mean of 0.89 on validation drives (seeds
    # 2000-2002, shipped cart-0.4 masker) but a mean d² of 143 on the held-out drives (560 on the
    # open road, where the ring yaw strays); 200 is conservative there (mean d² 9.4) instead.
    beta_yaw: float = 200.0

    def __post_init__(self):
        if self.angle_oversample < 1 or self.radii < 1:
            raise ValueError(f"{self}: angle_oversample and radii must be >= 1")
        if not 0.0 < self.radius_min < self.radius_max <= 0.98:
            raise ValueError(f"{self}: need 0 < radius_min < radius_max <= 0.98 (fractions of W/2)")
        if self.beta_yaw <= 0:
            raise ValueError(f"{self}: beta_yaw must be > 0")

    def label(self) -> str:
        """Short name for tables, e.g. ``a1r32``."""
        return f"a{self.angle_oversample}r{self.radii}"


DEFAULT_DECOUPLED = DecoupledSettings()


def ring_geometry(profile: GridProfile, settings: DecoupledSettings):
    """(angles, bin_rad, radii_px, shifts): the polar grid of the magnitude spectrum and the
    correlation shifts searched, in float64/int numpy.

    angles: float[A] in [0, π), φ = atan2(kc, kr) in the DFT's (row, column) frequency plane;
    radii_px: float[R] in frequency bins; shifts: int[2S + 1], −S..S angular bins with
    ``S·bin_rad`` = the profile's yaw range.
    """
    bin_rad = profile.rotation_step_rad / settings.angle_oversample
    a = math.pi / bin_rad
    if abs(a - round(a)) > 1e-6:
        raise ValueError(f"profile {profile.name!r}: the yaw step / angle_oversample does not divide 180°")
    a = int(round(a))
    half = profile.width_px / 2
    radii = np.linspace(settings.radius_min * half, settings.radius_max * half, settings.radii)
    s = (profile.num_rotations // 2) * settings.angle_oversample
    if 2 * s + 1 > a:
        raise ValueError(f"profile {profile.name!r}: the yaw range reaches ±90°; the magnitude spectrum "
                         "cannot tell yaw from yaw + 180°")
    return np.arange(a) * bin_rad, bin_rad, radii, np.arange(-s, s + 1)


def polar_positions(width_px: int, angles: np.ndarray, radii: np.ndarray):
    """float64 (rows, cols) [R, A] where ring r, angle a samples the row-centred half spectrum
    (row ``kr + W/2`` holds row frequency kr = −W/2..W/2 − 1, column kc = 0..W/2)."""
    kr = radii[:, None] * np.cos(angles)[None, :]
    kc = radii[:, None] * np.sin(angles)[None, :]
    return kr + width_px // 2, kc


# ============================================================================ stage 1: rotation
class RingCorrelation(nn.Module):
    """Natural half spectra → (yaw [B], yaw variance [B], correlation [B, 2S + 1]).

    Inputs: the previous and current sweeps' natural half spectra [B, 2, W, W//2 + 1]. The yaw
    is the current sweep's in the previous one's frame (radians, the Oxford convention of the
    pose): rotating the current features by it (`correlation.rotation_grids`) aligns them with
    the previous ones. See the module docstring, step 1.
    """

    def __init__(self, profile: GridProfile, settings: DecoupledSettings):
        super().__init__()
        angles, bin_rad, radii, shifts = ring_geometry(profile, settings)
        w = profile.width_px
        self.width_px, self.angles, self.ring_count = w, len(angles), len(radii)
        self.bin_rad = float(bin_rad)
        self.beta_yaw = float(settings.beta_yaw)
        rows, cols = polar_positions(w, angles, radii)
        index, fr, fc = bilinear_table(torch.from_numpy(rows), torch.from_numpy(cols), w, w // 2 + 1)
        self.register_buffer("index", index.reshape(1, -1), persistent=False)
        self.register_buffer("fr", fr.reshape(1, -1).to(torch.float32), persistent=False)
        self.register_buffer("fc", fc.reshape(1, -1).to(torch.float32), persistent=False)
        # real DFT along angles and the inverse at the searched shifts only (`dft`'s matrices)
        self.register_buffer("fwd", float32_buffer(forward_column_matrix(len(angles))), persistent=False)
        # c[s] = Σ_a P_prev(a)·P_cur(a + s) / A: the inverse of conj(F_prev)·F_cur at shift +s
        # (the matrix holds the 2-D inverse's 1/A²; a 1-D inverse is 1/A)
        self.register_buffer("inv", float32_buffer(half_spectrum_inverse_matrix(len(angles), shifts)
                                                   * float(len(angles))), persistent=False)
        self.register_buffer("yaws", torch.tensor(shifts * bin_rad, dtype=torch.float64).to(torch.float32),
                             persistent=False)

    def magnitudes(self, spectra: torch.Tensor) -> torch.Tensor:
        """Natural half spectra [M, 2, W, G] → ring profiles [M, R, A], each ring zero-mean:
        ``|F|`` resampled to the polar grid."""
        w = self.width_px
        power = spectra[:, 0] ** 2 + spectra[:, 1] ** 2  # [M, W, G]
        # the magnitude, with a floor that keeps the gradient finite at 0
        mag = torch.sqrt(power + 1e-12)
        centred = torch.cat([mag[:, w // 2:], mag[:, : w // 2]], dim=1)  # row kr + W/2
        flat = F.pad(centred, (1, 2, 1, 2)).reshape(mag.shape[0], -1)
        rings = gather_lerp(flat, self.index.expand(mag.shape[0], -1), self.fr, self.fc, w // 2 + 1 + 3)
        rings = rings.reshape(-1, self.ring_count, self.angles)
        return rings - rings.mean(dim=-1, keepdim=True)

    def forward(self, prev_state: torch.Tensor, cur_state: torch.Tensor):
        b = prev_state.shape[0]
        rings = self.magnitudes(torch.cat([prev_state, cur_state], dim=0))  # [2B, R, A]
        spec = rings @ self.fwd  # [2B, R, 2G'] = [re | im] along angles
        g = spec.shape[-1] // 2
        p, c = spec[:b], spec[b:]
        z_re = (p[..., :g] * c[..., :g] + p[..., g:] * c[..., g:]).sum(dim=1)  # Σ_rings conj(P)·C
        z_im = (p[..., :g] * c[..., g:] - p[..., g:] * c[..., :g]).sum(dim=1)
        corr = torch.cat([z_re, z_im], dim=-1) @ self.inv  # [B, 2S + 1]
        norm = torch.sqrt((rings[:b] ** 2).sum(dim=(1, 2)) * (rings[b:] ** 2).sum(dim=(1, 2)) + 1e-30)
        cosine = corr / norm.unsqueeze(-1)
        return (*peak_and_variance(cosine, self.yaws, self.bin_rad, self.beta_yaw), cosine)


def peak_and_variance(scores: torch.Tensor, yaws: torch.Tensor, bin_rad: float, beta: float):
    """(yaw [B], variance [B]) from scores [B, K] at the evenly spaced yaws [K] (step bin_rad).

    The yaw is the best score's, moved by a parabola through it and its two neighbours
    (``(c₋ − c₊) / (2 (c₋ − 2c₀ + c₊))`` bins, clipped to ±½; 0 on the border or where the
    parabola does not curve down). The variance is the second moment of ``softmax(β·scores)``
    about that yaw.
    """
    k = scores.shape[-1]
    best = scores.argmax(dim=-1, keepdim=True)  # [B, 1]
    lo, hi = (best - 1).clamp(min=0), (best + 1).clamp(max=k - 1)
    c0, cm, cp = scores.gather(1, best), scores.gather(1, lo), scores.gather(1, hi)
    curve = cm - 2.0 * c0 + cp
    inside = (best > 0) & (best < k - 1) & (curve < 0)
    delta = torch.where(inside, (cm - cp) / (2.0 * torch.where(inside, curve, -torch.ones_like(curve))),
                        torch.zeros_like(curve)).clamp(-0.5, 0.5)
    yaw = (yaws[best] + delta * bin_rad).squeeze(-1)
    w = torch.softmax(beta * scores, dim=-1)
    var = (w * (yaws.unsqueeze(0) - yaw.unsqueeze(-1)) ** 2).sum(dim=-1)
    return yaw, var


# ============================================================================ the step
class DecoupledStreamStep(nn.Module):
    """``(cur, prev_state) → (pose, covariance, new_state)`` like `fast_search.FastStreamStep`.

    Same inputs, outputs and state format (single mode; the state is the previous masked
    sweep's natural half spectrum [B, 2, W, W//2 + 1]): pose float[B, 3] (x m, y m, yaw rad,
    the current sweep in the previous one's frame), covariance float[B, 3, 3]. The search is the
    module docstring's: yaw from the magnitude spectra, then one translation correlation.

    Args:
        model: a single-mode `MaskedCorrelator` (its masker, polar mapping, βs and covariance
            scale/floor are used).
        settings: `DecoupledSettings` (default `DEFAULT_DECOUPLED`).
    """

    def __init__(self, model, settings: DecoupledSettings | None = None):
        super().__init__()
        if getattr(model, "dual", False):
            raise ValueError("DecoupledStreamStep needs a single-mode model: in dual mode the state is "
                             "the previous sweep and both masks are predicted together")
        p = model.profile
        self.model = model
        self.settings = st = settings or DEFAULT_DECOUPLED
        self.width_px, self.n = p.width_px, p.translation_cells
        self.spectrum = FactoredSpectrum(p.width_px)
        self.inverse = WindowedInverse(p.width_px, p.translation_cells)
        self.rings = RingCorrelation(p, st)
        self.rotation = CropRotation(p.width_px, p.translation_cells)
        offsets = torch.arange(-p.translation_cells, p.translation_cells + 1, dtype=torch.float64)
        self.register_buffer("offsets_m", (offsets * p.resolution_m).to(torch.float32), persistent=False)

    @property
    def profile(self) -> GridProfile:
        return self.model.profile

    def forward(self, cur: torch.Tensor, prev_state: torch.Tensor, cur_mask=None):
        features = self.model.sweep_features(cur, cur_mask)  # [B, W, W], support disc cut
        spec = self.spectrum(features)
        new_state = self.spectrum.to_natural(spec)
        pose, cov = self.match(prev_state, features, new_state)
        return pose, cov, new_state

    def match(self, prev_state: torch.Tensor, features: torch.Tensor, new_state: torch.Tensor):
        """(pose [B, 3], covariance [B, 3, 3]) of each current sweep in its previous one's frame,
        from the previous sweeps' natural spectra [B, 2, W, G] and the current sweeps' features
        [B, W, W] and natural spectra; batch items are independent pairs."""
        yaw, yaw_var, _ = self.rings(prev_state, new_state)
        rotated = self.rotation(features, yaw)
        volume = self.inverse(self.spectrum.from_natural(prev_state), self.spectrum(rotated).unsqueeze(1))
        pose, cov = search_soft_argmax(self.model, self.offsets_m, volume, yaw.unsqueeze(1))
        # the x/y block from the translation softmax, the yaw variance from the ring correlation
        # (one yaw: the volume's yaw moment and cross terms are 0)
        e = torch.zeros(3, 3, dtype=cov.dtype, device=cov.device)
        e[2, 2] = self.profile.cov_scale
        return pose, cov + yaw_var[:, None, None] * e



class CropRotation(nn.Module):
    """images [B, W, W] rotated by yaw [B] (radians) → [B, W, W]: ``S(R(yaw)ᵀ p)``, the convention
    and bilinear sampling (zeros outside) of `correlation.rotate_images`, computed on the central
    (W − 2n)² square only (the support disc's; outside it the result is 0).

    The sampling table depends on the yaw, so it is computed in the graph (a few elementwise ops
    on (W − 2n)² values) and read with four ``GatherElements`` (`gather_lerp`).
    """

    def __init__(self, width_px: int, translation_cells: int):
        super().__init__()
        self.width_px, self.n = int(width_px), int(translation_cells)
        c_w = (width_px - 1) / 2
        idx = torch.arange(self.n, width_px - self.n, dtype=torch.float64)
        # output pixels of the central square, metric (x up the rows, y along columns)
        self.register_buffer("x_px", (c_w - idx).to(torch.float32).reshape(-1, 1), persistent=False)
        self.register_buffer("y_px", (idx - c_w).to(torch.float32).reshape(1, -1), persistent=False)

    def forward(self, images: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
        b, w, n = images.shape[0], self.width_px, self.n
        c_w = (w - 1) / 2
        cos, sin = torch.cos(yaw).reshape(b, 1, 1), torch.sin(yaw).reshape(b, 1, 1)
        src_x = cos * self.x_px + sin * self.y_px  # R(yaw)ᵀ p, [B, w', w']
        src_y = -sin * self.x_px + cos * self.y_px
        index, fr, fc = bilinear_table(c_w - src_x, c_w + src_y, w, w)
        flat = F.pad(images, (1, 2, 1, 2)).reshape(b, -1)
        inner = gather_lerp(flat, index.reshape(b, -1), fr.reshape(b, -1), fc.reshape(b, -1), w + 3,
                            source_differences=True)
        return F.pad(inner.reshape(b, w - 2 * n, w - 2 * n), (n, n, n, n))


class DecoupledPairStep(nn.Module):
    """``(prev, cur) sweeps → (pose [B, 3], covariance [B, 3, 3])``: the decoupled search on pairs,
    for training through it (gradients reach the masker through both stages)."""

    def __init__(self, step: DecoupledStreamStep):
        super().__init__()
        self.step = step

    def forward(self, prev, cur, prev_mask=None, cur_mask=None):
        s = self.step
        f_prev, f_cur = s.model.features(prev, cur, prev_mask, cur_mask)
        both = s.spectrum.to_natural(s.spectrum(torch.stack([f_prev, f_cur])))
        return s.match(both[0], f_cur, both[1])
