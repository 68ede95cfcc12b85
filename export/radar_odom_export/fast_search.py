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
   and without the normalisation the energy it removes biases the pick towards yaw 0.
2. **Fine band** (`FastStreamStep`). The ``2b + 1`` consecutive candidates centred on that yaw
   (shifted, never truncated, to stay inside ±range) are evaluated at full resolution over the
   whole translation window, and so is yaw 0, whose spectrum is the new state's (no extra
   rotation or DFT): driving straight is the common case, and the rare coarse pick that strays
   (1 of 956 held-out steps at 0.4 m/px) then still finds the straight-ahead match.
3. **Soft-argmax over the evaluated yaws** (paper eq. 3): pose and covariance from the band's
   and yaw 0's candidates. Candidates outside get no weight, so **the covariance's yaw extent is
   limited to the band (and yaw 0)**, ``2b + 1`` steps wide. With a band covering every candidate
   (and ``rotation="bilinear"``) the step equals the exhaustive one (tests/test_fast_search.py).

**Rotation** (`PolarRotator`). onnxruntime's ``GridSample`` runs on one thread at ~20 ns per
sample, slower than the DFTs it feeds. Rotation about the centre is a shift along azimuth in
polar coordinates, so the image is resampled once onto a polar grid (two rows per yaw step,
a radius every 0.5 px: oversampled so that the round trip blurs about as much as one bilinear
rotation), rolled by whole rows for each candidate and resampled back with one table shared by
every candidate; both resamplings are bilinear ``GatherElements`` with constant tables computed
in the graph (folded by onnxruntime at session start). Yaw 0 uses the image itself, exactly as
the exhaustive step's `Rotator` does. ``rotation="bilinear"`` keeps ``grid_sample``.

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

The graph has static shapes and uses MatMul, GatherElements, Gather, ArgMax, elementwise and
shape ops: no ``DFT``/``STFT`` node, no complex tensor. `export_fast` writes it with the same
contract as `onnx_export.export_model` (stream form) plus ``radar_odom.search`` metadata.
"""
from __future__ import annotations

import copy
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import GridProfile

from .correlation import rotation_grids
from .softargmax import candidate_weights, parabolic_peak, peak_window, pose_window, windowed_weights

TAU = 2.0 * math.pi
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
DEFAULT_SETTINGS = {
    128: FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=2),
    256: FastSearchSettings(coarse_factor=4, coarse_stride=2, band_half_width=2),
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


# ============================================================================ factored DFT
def dft_split(width_px: int) -> tuple[int, int]:
    """(P, Q) with ``P·Q = W``, P a power of two ≤ √W (P = 1: no factorisation possible)."""
    p = 1
    while (2 * p) ** 2 <= width_px and width_px % (2 * p) == 0:
        p *= 2
    return p, width_px // p


def _f32(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64).astype(np.float32))


def _angles(a: np.ndarray, b: np.ndarray, period: int) -> np.ndarray:
    """2π·(a ⊗ b mod period)/period in float64; reducing the integer product first keeps
    the angles exact for any size."""
    return TAU * (np.multiply.outer(a, b) % period) / period


def natural_rows(width_px: int) -> np.ndarray:
    """int[W]: the row frequency kr held at each row position of the factored spectrum."""
    p, q = dft_split(width_px)
    return (np.arange(p)[:, None] + p * np.arange(q)[None, :]).ravel()


def natural_cols(width_px: int) -> np.ndarray:
    """int[P, H]: the column frequency kc held at each (kc1, kc2) of the factored spectrum.

    Values above W/2 are redundant (Hermitian mirrors); the inverse gives them zero weight.
    """
    p, q = dft_split(width_px)
    return np.arange(p)[:, None] + p * np.arange(q // 2 + 1)[None, :]


def hermitian_weights(kc: np.ndarray, width_px: int) -> np.ndarray:
    """Weight of column frequency kc in a real inverse from the half spectrum: 1 at 0 and at
    W/2 (its own mirror), 2 in between (the mirror's share), 0 beyond W/2 (counted already)."""
    w = np.where(kc < (width_px + 1) / 2, 2.0, 0.0)
    w[kc == 0] = 1.0
    if width_px % 2 == 0:
        w[kc == width_px // 2] = 1.0
    return w


class FactoredSpectrum(nn.Module):
    """Real images float[..., W, W] → half spectrum in factored order float[..., P, W, 2, H].

    Rows r = Q·r1 + r2 and columns c = Q·c1 + c2; the output holds ``X(kr, kc)`` at
    ``[kc1, kr1·Q + kr2, re/im, kc2]`` with ``kr = kr1 + P·kr2``, ``kc = kc1 + P·kc2``
    (`natural_rows`, `natural_cols`), same sign and scale as ``torch.fft.rfft2``.
    Stages (each one matmul): DFT_P over r1 (real in); DFT_Q over r2 with the twiddle
    ``e^{−2πi·r2·kr1/W}`` (batched per kr1); DFT_P over c1; one transpose; DFT_Q over c2 with
    its twiddle, keeping ``kc2 ≤ Q/2`` (H = Q//2 + 1), which covers every kc ≤ W/2.
    """

    def __init__(self, width_px: int):
        super().__init__()
        w = self.width_px = int(width_px)
        p, q = self.p, self.q = dft_split(w)
        h = self.h = q // 2 + 1
        ip, iq, ih = np.arange(p), np.arange(q), np.arange(h)
        # stage 1, real input: rows (kr1, re/im) × r1
        th = _angles(ip, ip, p)
        s1 = np.stack([np.cos(th), -np.sin(th)], axis=1).reshape(2 * p, p)
        # stage 2, per kr1: rows (kr2, re/im) × (re/im, r2); angle kr2·r2/Q + kr1·r2/W
        s2 = np.zeros((p, q, 2, 2, q))
        for k1 in range(p):
            th = TAU * ((np.multiply.outer(iq, iq) * p + k1 * iq[None, :]) % w) / w
            _complex_block(s2[k1], np.cos(th), np.sin(th))
        # stage 3, complex, one matrix: rows (kc1, re/im) × (re/im, c1)
        s3 = np.zeros((p, 2, 2, p))
        th = _angles(ip, ip, p)
        _complex_block(s3, np.cos(th), np.sin(th))
        # stage 4, per kc1, right-multiplied: (re/im, c2) × (re/im, kc2)
        s4 = np.zeros((p, 2, q, 2, h))
        for k1 in range(p):
            th = TAU * ((np.multiply.outer(iq, ih) * p + k1 * iq[:, None]) % w) / w
            c, s = np.cos(th), np.sin(th)  # [c2, kc2]
            s4[k1, 0, :, 0], s4[k1, 1, :, 0] = c, s  # re' = c·re + s·im
            s4[k1, 0, :, 1], s4[k1, 1, :, 1] = -s, c  # im' = c·im − s·re
        for name, m in (("s1", s1), ("s2", s2.reshape(p, 2 * q, 2 * q)),
                        ("s3", s3.reshape(2 * p, 2 * p)), ("s4", s4.reshape(p, 2 * q, 2 * h))):
            self.register_buffer(name, _f32(m), persistent=False)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        w, p, q, h = self.width_px, self.p, self.q, self.h
        lead = images.shape[:-2]
        t = self.s1 @ images.reshape(*lead, p, q * w)  # [.., (kr1 ri), (r2 c)]
        t = self.s2 @ t.reshape(*lead, p, 2 * q, w)  # [.., kr1, (kr2 ri), c]
        t = self.s3 @ t.reshape(*lead, w, 2 * p, q)  # [.., kr, (kc1 ri), c2]
        t = t.reshape(*lead, w, p, 2 * q).transpose(-3, -2)  # [.., kc1, kr, (ri c2)]
        return (t @ self.s4).reshape(*lead, p, w, 2, h)

    # Converting orders is one GatherElements with a constant index (folded at session start):
    # onnxruntime's scalar Gather and its 5-D Transpose are several times slower.
    def _factored_index(self) -> torch.Tensor:
        """int64[P·W·2·H]: flat natural position [2, W, G] read by each factored entry
        (entries above W/2, the redundant mirrors, read column W/2: the inverse ignores them)."""
        w, p, q, h = self.width_px, self.p, self.q, self.h
        g = w // 2 + 1
        kc1 = torch.arange(p).reshape(p, 1, 1, 1, 1)
        kr1 = torch.arange(p).reshape(1, p, 1, 1, 1)
        kr2 = torch.arange(q).reshape(1, 1, q, 1, 1)
        ri = torch.arange(2).reshape(1, 1, 1, 2, 1)
        kc2 = torch.arange(h).reshape(1, 1, 1, 1, h)
        kc = (kc1 + p * kc2).clamp(max=g - 1)
        return ((ri * w + kr1 + p * kr2) * g + kc).reshape(-1)

    def _natural_index(self) -> torch.Tensor:
        """int64[2·W·G]: flat factored position [P, W, 2, H] holding each natural entry."""
        w, p, q, h = self.width_px, self.p, self.q, self.h
        g = w // 2 + 1
        ri = torch.arange(2).reshape(2, 1, 1)
        kr = torch.arange(w).reshape(1, w, 1)
        kc = torch.arange(g).reshape(1, 1, g)
        row = (kr % p) * q + kr // p
        return ((((kc % p) * w + row) * 2 + ri) * h + kc // p).reshape(-1)

    def to_natural(self, spec: torch.Tensor) -> torch.Tensor:
        """[..., P, W, 2, H] → the natural half spectrum [..., 2, W, W//2 + 1] (the state)."""
        lead = spec.shape[:-4]
        flat = spec.reshape(-1, self.p * self.width_px * 2 * self.h)
        index = self._natural_index().to(spec.device).unsqueeze(0).expand(flat.shape[0], -1)
        return torch.gather(flat, 1, index).reshape(*lead, 2, self.width_px, self.width_px // 2 + 1)

    def from_natural(self, state: torch.Tensor) -> torch.Tensor:
        """The natural half spectrum [..., 2, W, W//2 + 1] → factored order [..., P, W, 2, H]."""
        lead = state.shape[:-3]
        flat = state.reshape(-1, 2 * self.width_px * (self.width_px // 2 + 1))
        index = self._factored_index().to(state.device).unsqueeze(0).expand(flat.shape[0], -1)
        return torch.gather(flat, 1, index).reshape(*lead, self.p, self.width_px, 2, self.h)


def _complex_block(out: np.ndarray, c: np.ndarray, s: np.ndarray) -> None:
    """Fill ``out[k, ri', ri, n]`` with the real 2×2 blocks of multiplying by ``c − i·s``."""
    out[:, 0, 0], out[:, 0, 1] = c, s  # re' = c·re + s·im
    out[:, 1, 0], out[:, 1, 1] = -s, c  # im' = −s·re + c·im


class WindowedInverse(nn.Module):
    """Correlation volume float[B, K, N, N] from factored spectra (see `FactoredSpectrum`).

    ``C[k, i, j] = Re IDFT2(conj(A)·B_k)(u = i, v = −j)`` for i, j = −n..n: the layout and sign
    conventions of `correlation.py` (volume axis 2 ↔ x rows, axis 3 ↔ y columns). Only the
    N = 2n + 1 candidate shifts are computed: one matmul over the row frequencies (W → 2N
    cos/sin rows), a small transpose, one matmul over the column frequencies with Hermitian
    weights (the real part of the full inverse), scaled by 1/W².
    """

    def __init__(self, width_px: int, translation_cells: int):
        super().__init__()
        w, n = int(width_px), int(translation_cells)
        self.width_px, self.n = w, n
        self.p, _ = dft_split(w)
        u = np.arange(-n, n + 1)
        kr = natural_rows(w)
        th = _angles(u, kr, w)  # [N, W positions]
        self.register_buffer("rows", _f32(np.concatenate([np.cos(th), np.sin(th)])),
                             persistent=False)
        # Y(u, j) = Σ_kc w·[cos θ·(C·Zre − S·Zim) − sin θ·(S·Zre + C·Zim)], θ = 2π·kc·(−j)/W:
        # one matrix over (cos/sin row half, re/im, kc1, kc2) gives the real part directly
        kc = natural_cols(w)  # [P, H]
        wt = hermitian_weights(kc, w) / float(w) ** 2
        th = _angles(kc, -u, w)  # [P, H, N]
        cw, sw = wt[..., None] * np.cos(th), wt[..., None] * np.sin(th)
        m = np.stack([np.stack([cw, -sw]), np.stack([-sw, -cw])])  # [cs, ri, P, H, N]
        self.register_buffer("cols", _f32(m.transpose(2, 0, 1, 3, 4).reshape(-1, len(u))),
                             persistent=False)

    def forward(self, prev: torch.Tensor, cur: torch.Tensor) -> torch.Tensor:
        """prev [B, P, W, 2, H], cur [B, K, P, W, 2, H] → volume [B, K, N, N]."""
        a = prev.unsqueeze(1)
        a_re, a_im = a[..., 0, :], a[..., 1, :]
        b_re, b_im = cur[..., 0, :], cur[..., 1, :]
        z = torch.stack([a_re * b_re + a_im * b_im, a_re * b_im - a_im * b_re], dim=-2)  # conj(A)·B
        lead = z.shape[:-3]  # [B, K, P]
        t = self.rows @ z.reshape(*lead, self.width_px, -1)  # [B, K, P, 2N, 2H]
        n_out = 2 * self.n + 1
        t = t.reshape(*lead, 2 * n_out, -1).reshape(*lead[:-1], self.p, 2, n_out, -1)
        t = t.permute(0, 1, 4, 2, 3, 5).reshape(*lead[:-1], n_out, -1)  # [B, K, N, (P cs ri H)]
        return t @ self.cols


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


class LowResImage(nn.Module):
    """Natural half spectrum [..., 2, w, w//2+1] → the real image [..., w, w] (matmul iDFT)."""

    def __init__(self, width_px: int):
        super().__init__()
        w = int(width_px)
        g = w // 2 + 1
        th = _angles(np.arange(w), np.arange(w), w)  # [r, kr]
        c, s = np.cos(th), np.sin(th)
        # rows: complex e^{+iθ}: re' = c·re − s·im, im' = s·re + c·im; one [2w, 2w] matrix
        self.register_buffer("rows", _f32(np.block([[c, -s], [s, c]])), persistent=False)
        kc = np.arange(g)
        wt = hermitian_weights(kc, w)[:, None] / float(w) ** 2
        th = _angles(kc, np.arange(w), w)  # [kc, c]
        self.register_buffer("cols", _f32(np.concatenate([wt * np.cos(th), -wt * np.sin(th)])),
                             persistent=False)
        self.width_px = w

    def forward(self, spec: torch.Tensor) -> torch.Tensor:
        lead = spec.shape[:-3]
        w = self.width_px
        t = self.rows @ spec.reshape(*lead, 2 * w, -1)  # [.., (ri r), kc]
        t = t.reshape(*lead, 2, w, -1).movedim(-3, -2).reshape(*lead, w, -1)  # [.., r, (ri kc)]
        return t @ self.cols


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
        self.index_list = idx
        yaws = torch.tensor(profile.rotations_rad, dtype=torch.float64)[idx]
        self.register_buffer("yaws", yaws.to(torch.float32), persistent=False)
        self.rotator = (None if settings.rotation == "bilinear" else
                        PolarRotator(self.low_px, profile.rotation_step_rad, (self.low_px - 1) / 2, centre))
        self.image = LowResImage(self.low_px)
        self.spectrum = FactoredSpectrum(self.low_px)
        self.inverse = WindowedInverse(self.low_px, max(1, math.ceil(profile.translation_cells / f)))

    def forward(self, prev_state: torch.Tensor, cur_state: torch.Tensor) -> torch.Tensor:
        prev = self.spectrum.from_natural(crop_spectrum(prev_state, self.width_px, self.low_px))
        cur = self.image(crop_spectrum(cur_state, self.width_px, self.low_px))  # [B, w, w]
        b = cur.shape[0]
        if self.rotator is None:
            rotated = _rotate_bilinear(cur, self.yaws.unsqueeze(0).expand(b, -1))
        else:
            rotated = self.rotator.rotate_constant(cur, [i - self.centre for i in self.index_list])
        volume = self.inverse(prev, self.spectrum(rotated))  # [B, Kc, n, n]
        # Normalised by each rotated image's norm: interpolation blurs every rotation but the
        # identity, and the energy it removes would otherwise pull the pick towards yaw 0.
        norm = torch.sqrt((rotated * rotated).flatten(2).sum(dim=-1) + 1e-12)
        best = (volume.flatten(2).amax(dim=-1) / norm).argmax(dim=-1)
        return self.indices[best]


def _rotate_bilinear(images: torch.Tensor, yaws: torch.Tensor) -> torch.Tensor:
    """images [B, W, W] rotated by yaws [B, K] → [B, K, W, W] with ``grid_sample`` (bilinear,
    zeros outside): exactly the exhaustive step's rotation (`correlation.rotation_grids`)."""
    b, k = yaws.shape
    w = images.shape[-1]
    grids = rotation_grids(yaws.reshape(-1), w)
    stack = images.unsqueeze(1).expand(b, k, w, w).reshape(b * k, 1, w, w)
    out = F.grid_sample(stack, grids, mode="bilinear", padding_mode="zeros", align_corners=True)
    return out.reshape(b, k, w, w)


def _bilinear_table(rows: torch.Tensor, cols: torch.Tensor, height: int, width: int):
    """Where samples at pixel positions (rows, cols) read a source [height, width] padded with
    zeros by 1 px before and 2 px after on both axes: (flat index of the top-left neighbour
    int64, row fraction, column fraction). Positions outside clamp into the zero border."""
    rows = rows.clamp(-1.0, float(height))
    cols = cols.clamp(-1.0, float(width))
    r0, c0 = torch.floor(rows), torch.floor(cols)
    index = ((r0 + 1.0) * (width + 3) + (c0 + 1.0)).to(torch.int64)
    return index, rows - r0, cols - c0


def _bilinear_sample(source: torch.Tensor, table, width: int) -> torch.Tensor:
    """source [N, H, width] sampled at a `_bilinear_table` [M] (same for every n) → [N, M].

    Four ``GatherElements`` and two-level linear interpolation; onnxruntime's ``GridSample``
    is single-threaded and several times slower, and plain ``Gather`` on scalars is slower still.
    """
    index, fr, fc = table
    n = source.shape[0]
    flat = F.pad(source, (1, 2, 1, 2)).reshape(n, -1)
    stride = width + 3
    index = index.reshape(1, -1).expand(n, -1)

    def at(offset):
        return torch.gather(flat, 1, index + offset if offset else index)

    top = at(0)
    top = top + fc.reshape(1, -1) * (at(1) - top)
    bottom = at(stride)
    bottom = bottom + fc.reshape(1, -1) * (at(stride + 1) - bottom)
    return top + fr.reshape(1, -1) * (bottom - top)


class PolarRotator(nn.Module):
    """Rotate images by whole yaw steps through one shared polar resampling.

    Rotating about the image centre is a shift along azimuth in polar coordinates. The image
    is resampled once onto a polar grid (``oversample`` rows per yaw step, a radius every
    ``radial_step_px`` up to ``radius_px``; oversampling keeps the round trip's blur small and
    alike for every rotation); rotation by s steps is a roll of that grid, and each rotated image
    is resampled back to Cartesian with one table shared by all rotations. The tables depend
    only on the geometry: they are computed in the graph from a few constants and folded by
    onnxruntime at session start, so the file stays small. Both resamplings are bilinear with
    zeros outside; the result differs from direct bilinear rotation (`_rotate_bilinear`) by the
    second interpolation, a slight blur (the accuracy is measured in benchmarks/).
    """

    def __init__(self, width_px: int, step_rad: float, radius_px: float, max_shift: int,
                 oversample: int = 2, radial_step_px: float = 0.5):
        super().__init__()
        steps = 2 * math.pi / step_rad
        if abs(steps - round(steps)) > 1e-6:
            raise ValueError(f"rotation step {step_rad} rad does not divide the full turn; "
                             "use rotation='bilinear'")
        self.width_px = int(width_px)
        self.oversample = int(oversample)  # polar rows per yaw step
        self.azimuths = int(round(steps)) * self.oversample
        self.bin_rad = float(step_rad) / self.oversample
        self.radial_step_px = float(radial_step_px)
        self.radii = int(math.ceil(radius_px / self.radial_step_px)) + 2
        self.max_shift = int(max_shift) * self.oversample  # in polar rows

    def _tables(self, dtype):
        w, a, r = self.width_px, self.azimuths, self.radii
        c_w = (w - 1) / 2
        phi = torch.arange(a, dtype=dtype) * self.bin_rad
        rho = torch.arange(r, dtype=dtype) * self.radial_step_px
        # polar sample (rho, phi) sits at x = rho·cos φ (up the rows), y = rho·sin φ (columns)
        to_polar = _bilinear_table(c_w - rho[None, :] * torch.cos(phi)[:, None],
                                   c_w + rho[None, :] * torch.sin(phi)[:, None], w, w)
        idx = torch.arange(w, dtype=dtype)
        x = (c_w - idx)[:, None].expand(w, w)
        y = (idx - c_w)[None, :].expand(w, w)
        az = torch.atan2(y, x)
        az = torch.where(az < 0, az + 2 * math.pi, az) / self.bin_rad
        return to_polar, (az.reshape(-1), torch.sqrt(x * x + y * y).reshape(-1) / self.radial_step_px)

    def _wrapped_polar(self, images: torch.Tensor):
        """images [B, W, W] → polar grid [B, A + 2m + 1, R] whose row m + j is azimuth j
        (j = −m..A + m, wrapped), and the Cartesian positions (azimuth row, radius) [W·W]."""
        a, m = self.azimuths, self.max_shift
        to_polar, (az, rho) = self._tables(images.dtype)
        polar = _bilinear_sample(images, to_polar, self.width_px).reshape(-1, a, self.radii)
        return torch.cat([polar[:, a - m:], polar, polar[:, : m + 1]], dim=1), az, rho

    def forward(self, images: torch.Tensor, shifts: torch.Tensor) -> torch.Tensor:
        """images [B, W, W], shifts int64[B, K] (yaw = shift·step) → [B, K, W, W]."""
        b, k = shifts.shape
        w, a, m, r = self.width_px, self.azimuths, self.max_shift, self.radii
        wrapped, az, rho = self._wrapped_polar(images)
        # rotation by s: row j of the rolled grid is azimuth j − s, rows m − s .. m − s + A
        rows = (m - self.oversample * shifts).reshape(b, k, 1) + torch.arange(a + 1, device=shifts.device)
        rows = rows + torch.arange(b, device=shifts.device).reshape(b, 1, 1) * wrapped.shape[1]
        rolled = wrapped.reshape(-1, r).index_select(0, rows.reshape(-1))
        table = _bilinear_table(az, rho, a + 1, r)
        out = _bilinear_sample(rolled.reshape(b * k, a + 1, r), table, r)
        return out.reshape(b, k, w, w)

    def rotate_constant(self, images: torch.Tensor, shifts) -> torch.Tensor:
        """images [B, W, W] rotated by fixed shifts (a list of ints) → [B, K, W, W].

        With fixed shifts the roll folds into the sampling table (constant, folded at session
        start), so no rolled copies of the polar grid are made.
        """
        w, m, r = self.width_px, self.max_shift, self.radii
        wrapped, az, rho = self._wrapped_polar(images)
        offsets = torch.tensor([m - self.oversample * int(s) for s in shifts], dtype=images.dtype)
        table = _bilinear_table(az.reshape(1, -1) + offsets.reshape(-1, 1),
                                rho.reshape(1, -1).expand(len(shifts), -1), wrapped.shape[1], r)
        out = _bilinear_sample(wrapped, table, r)
        return out.reshape(images.shape[0], len(shifts), w, w)


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
                        PolarRotator(p.width_px, p.rotation_step_rad, disc_px, p.num_rotations // 2))
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
        indices = self.band_indices(prev_state, new_state)  # [B, Kb]
        # Yaw 0 is scored as well, from the spectrum already computed for the new state (no extra
        # rotation or DFT): driving straight is the common case, and a coarse pick that strays
        # (rare, at ~0.1 % of held-out steps) then still finds the straight-ahead match. When the
        # band holds yaw 0 already, the extra slice gets no weight (it would count twice).
        zero = torch.full_like(indices[:, :1], self.num_rotations // 2)
        has_zero = (indices == zero).any(dim=1, keepdim=True)  # [B, 1]
        spectra = torch.cat([self.spectrum(self.rotate(features, indices)), spec.unsqueeze(1)], dim=1)
        volume = self.inverse(self.spectrum.from_natural(prev_state), spectra)  # [B, Kb + 1, N, N]
        drop = torch.cat([torch.zeros_like(indices, dtype=torch.bool), has_zero], dim=1)
        volume = volume.masked_fill(drop[:, :, None, None], NO_WEIGHT)
        pose, cov = self.soft_argmax(volume, self.yaw_table[torch.cat([indices, zero], dim=1)])
        return pose, cov, new_state

    def rotate(self, features: torch.Tensor, indices: torch.Tensor) -> torch.Tensor:
        """features [B, W, W] rotated by the yaw candidates ``indices`` int64[B, Kb] → [B, Kb, W, W]."""
        if self.rotator is None:
            return _rotate_bilinear(features, self.yaw_table[indices])
        shifts = indices - self.num_rotations // 2
        rotated = self.rotator(features, shifts)
        # yaw 0 is the image itself, exactly as in the exhaustive step (`Rotator`): the polar
        # round trip would blur it like every other yaw and move weight off the peak
        return torch.where((shifts == 0)[:, :, None, None], features.unsqueeze(1), rotated)

    def soft_argmax(self, volume: torch.Tensor, yaws: torch.Tensor):
        """Paper eq. 3 over the evaluated yaws: volume [B, K', N, N], yaws [B, K'] → pose, covariance."""
        p = self.profile
        if p.pose_estimator == "parabolic":  # as `softargmax.read_pose`, on the band's yaws
            pose = parabolic_peak(volume, self.offsets_m, self.offsets_m, yaws, p.rotation_step_rad)
        else:
            window = pose_window(p)
            mask = None if window is None else peak_window(volume, self.offsets_m, self.offsets_m, yaws, *window)
            pose, _ = band_moments(windowed_weights(volume, p.beta_pose, mask), self.offsets_m, yaws)
        _, cov = band_moments(candidate_weights(volume, p.beta_cov).reshape(volume.shape), self.offsets_m, yaws)
        return pose, cov + self.model.cov_floor


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


# ============================================================================ export
class _StreamGraph(nn.Module):
    def __init__(self, step: FastStreamStep):
        super().__init__()
        self.step = step

    def forward(self, sweep, prev_state):
        return self.step(sweep, prev_state)


def export_fast(model, path, settings: FastSearchSettings | None = None, *, opset: int | None = None,
                masking: str | None = None, training_data=None, verify: bool = True):
    """Export ``model`` in the stream form with the fast search; the same file contract as
    `onnx_export.export_model` (inputs ``cart``/``polar`` + ``prev_state``; outputs ``pose``,
    ``covariance``, ``state``; metadata, checks), plus ``radar_odom.search`` metadata.

    Returns the `onnx_export.ExportReport`.
    """
    import onnx

    from . import onnx_export as ox

    opset = opset or ox.DEFAULT_OPSET
    t0 = time.perf_counter()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    m = copy.deepcopy(model).cpu().eval()
    step = FastStreamStep(m, settings).eval()
    inputs = ox.example_inputs(m, "stream")
    input_names, output_names = ox.io_names(m, "stream")
    with torch.no_grad():
        ox._torch_export(_StreamGraph(step), inputs, path, input_names, output_names, opset, dynamo=True)
    proto = onnx.load(str(path))
    meta = ox.build_metadata(m, "stream", opset, "dynamo", masking or m.masking, training_data,
                             tuple(inputs[1].shape))
    meta["radar_odom.search"] = json.dumps({"kind": "coarse_to_fine", **asdict(step.settings),
                                            "band_rotations": step.band}, sort_keys=True)
    ox.strip_node_metadata(proto)
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    proto.doc_string = (f"radar-odom: Masking by Moving radar odometry, profile {m.profile.name}, "
                        f"stream form, fast search {step.settings.label()}")
    onnx.save(proto, str(path))
    checked = ox.check_onnx_file(path, opset)
    report = ox.ExportReport(path, "stream", "dynamo", checked["opset"], checked["bytes"], checked["ops"],
                             meta, time.perf_counter() - t0)
    if verify:
        report.max_pose_diff = _verify(path, step, inputs)
        report.seconds = time.perf_counter() - t0
    return report


def _verify(path, step, inputs) -> float:
    """max |pose_ORT − pose_torch| of the exported fast step on the export's example inputs."""
    from radar_odom.onnx_model import OnnxModel

    ort_model = OnnxModel(path)
    with torch.no_grad():
        ref = step(*inputs)
    out = ort_model.run({n: x.numpy() for n, x in zip(ort_model.info.inputs, inputs)})
    return float(np.max(np.abs(out["pose"] - ref[0].numpy())))
