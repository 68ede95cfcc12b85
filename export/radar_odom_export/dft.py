"""Matmul DFTs: the export backend's correlation and the fast search's factored transforms.

The ONNX ``DFT`` op runs only on onnxruntime's CPU provider and complex tensors do not export,
so here every transform is a real matmul with constant cos/sin matrices (built in float64,
stored float32) on separate real and imaginary parts. Every matrix is built here, from one
angle helper (`angles`) and one set of Hermitian weights (`hermitian_weights`).

`MatmulDFTCorrelation` (the exhaustive step's backend, the interface of `FFTCorrelation`):

* forward (``spectrum``): real-input half spectrum along columns (W//2 + 1 frequencies, one
  ``[W, 2G]`` matmul giving re and im at once), then the full complex DFT along rows (one
  ``[2W, W]`` matmul whose two halves combine into re and im);
* cross-power ``conj(prev) · cur`` elementwise on (re, im) pairs;
* windowed inverse (``correlate``): only the N = 2n + 1 candidate shifts per axis are computed,
  with ``[2N, W]`` and ``[2G, N]`` matrices instead of a full inverse. The half spectrum is
  summed with Hermitian weights (1 at g = 0 and, for even W, at g = W/2; 2 elsewhere) and only
  the real part is kept, which is exact because the full-spectrum sum is real.

The fast search's transforms (`fast_search`): `FactoredSpectrum` (four-step Cooley–Tukey
factorisation ``W = P·Q``, spectrum in a permuted order), `WindowedInverse` (the windowed inverse
on that order: the same row and column matrices as above, permuted) and `LowResImage` (a full
matmul inverse of a small image).

Conventions (sign, layout, circularity) are those of ``correlation.py``'s module docstring.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

TAU = 2.0 * math.pi


def angles(a, b, period: int) -> np.ndarray:
    """float64 ``2π·(a ⊗ b mod period)/period``: reducing the integer product first keeps the
    angles exact for any size."""
    return TAU * (np.multiply.outer(a, b) % period) / period


def hermitian_weights(kc, width_px: int) -> np.ndarray:
    """Weight of column frequency kc in a real inverse from the half spectrum: 1 at 0 and at
    W/2 (its own mirror), 2 in between (the mirror's share), 0 beyond W/2 (counted already)."""
    kc = np.asarray(kc)
    w = np.where(kc < (width_px + 1) / 2, 2.0, 0.0)
    w[kc == 0] = 1.0
    if width_px % 2 == 0:
        w[kc == width_px // 2] = 1.0
    return w


def float32_buffer(a: np.ndarray) -> torch.Tensor:
    """A float64 matrix rounded once to a float32 tensor (a module buffer)."""
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64).astype(np.float32))


def half_spectrum_size(width_px: int) -> int:
    """G: frequencies kept along the real-input (column) axis."""
    return width_px // 2 + 1


def forward_column_matrix(width_px: int) -> np.ndarray:
    """float64[W, 2G]: ``S @ M = [Re | Im]`` of the DFT of each row of S over columns (g ≤ W/2).

    ``M[c, g] = cos(2π c g / W)`` and ``M[c, G + g] = −sin(2π c g / W)`` (forward sign e^{−iθ}).
    """
    theta = angles(np.arange(width_px), np.arange(half_spectrum_size(width_px)), width_px)
    return np.concatenate([np.cos(theta), -np.sin(theta)], axis=1)


def forward_row_matrix(width_px: int) -> np.ndarray:
    """float64[2W, W]: ``[cos; sin](2π f r / W)``; ``M @ P`` gives the four real products
    from which the complex row DFT ``(cos − i·sin) @ (P_re + i·P_im)`` is assembled."""
    theta = angles(np.arange(width_px), np.arange(width_px), width_px)
    return np.concatenate([np.cos(theta), np.sin(theta)], axis=0)


def inverse_row_matrix(width_px: int, translation_cells: int, freqs=None) -> np.ndarray:
    """float64[2N, W]: ``[cos; sin](2π f u / W)`` for the row shifts u = −n..n only.

    ``freqs``: the row frequency held at each input position (default 0..W−1, natural order).
    """
    n = translation_cells
    freqs = np.arange(width_px) if freqs is None else freqs
    theta = angles(np.arange(-n, n + 1), freqs, width_px)
    return np.concatenate([np.cos(theta), np.sin(theta)], axis=0)


def inverse_column_terms(kc, shifts, width_px: int) -> tuple[np.ndarray, np.ndarray]:
    """``(w·cos θ, w·sin θ) / W²`` with ``θ = 2π·kc·v/W``, shape ``kc.shape + shifts.shape``:
    the half-spectrum column frequencies kc (Hermitian weights w) against column shifts v."""
    wt = hermitian_weights(kc, width_px) / float(width_px) ** 2
    theta = angles(kc, shifts, width_px)
    return wt[..., None] * np.cos(theta), wt[..., None] * np.sin(theta)


def half_spectrum_inverse_matrix(width_px: int, shifts) -> np.ndarray:
    """float64[2G, len(shifts)]: ``[Y_re | Y_im] @ M`` is the real inverse over columns at the
    column shifts ``shifts``, with Hermitian weights and the full 1/W² of the 2-D inverse."""
    c, s = inverse_column_terms(np.arange(half_spectrum_size(width_px)), shifts, width_px)
    return np.concatenate([c, -s], axis=0)


def inverse_column_matrix(width_px: int, translation_cells: int) -> np.ndarray:
    """float64[2G, N]: ``[Y_re | Y_im] @ M`` is the real windowed inverse over columns.

    Output column ``j + n`` (j = −n..n) is the shift v = −j (volume axis 3 grows with +y while
    the correlation shift grows with columns of the *current* image, see correlation.py).
    ``M[g, ·] = w_g·cos(2π g v / W) / W²``, ``M[G + g, ·] = −w_g·sin(2π g v / W) / W²``, with
    Hermitian weights w_g and the full 1/W² normalisation of the 2-D inverse.
    """
    n = translation_cells
    return half_spectrum_inverse_matrix(width_px, -np.arange(-n, n + 1))


class MatmulDFTCorrelation(nn.Module):
    """Correlation volume from real matmuls only: no ``torch.fft``, no complex dtype."""

    def __init__(self, width_px: int, translation_cells: int):
        super().__init__()
        self.width_px = width_px
        self.translation_cells = translation_cells
        for name, matrix in (
            ("fwd_cols", forward_column_matrix(width_px)),
            ("fwd_rows", forward_row_matrix(width_px)),
            ("inv_rows", inverse_row_matrix(width_px, translation_cells)),
            ("inv_cols", inverse_column_matrix(width_px, translation_cells)),
        ):
            self.register_buffer(name, float32_buffer(matrix), persistent=False)

    def spectrum(self, images: torch.Tensor) -> torch.Tensor:
        """float[..., W, W] → half spectrum float[..., 2, W, W//2 + 1] (re, im)."""
        w, g = self.width_px, half_spectrum_size(self.width_px)
        cols = images @ self.fwd_cols  # [..., W, 2G] = [P_re | P_im]
        both = self.fwd_rows @ cols  # [..., 2W, 2G] = [[C·P_re, C·P_im], [S·P_re, S·P_im]]
        re = both[..., :w, :g] + both[..., w:, g:]  # C·P_re + S·P_im
        im = both[..., :w, g:] - both[..., w:, :g]  # C·P_im − S·P_re
        return torch.stack([re, im], dim=-3)

    def correlate(self, prev_spectrum: torch.Tensor, cur_spectra: torch.Tensor) -> torch.Tensor:
        """Volume float[B, K, N, N] from prev [B, 2, W, G] and rotated current [B, K, 2, W, G]."""
        n_out = 2 * self.translation_cells + 1
        g = half_spectrum_size(self.width_px)
        a_re, a_im = prev_spectrum[:, 0:1], prev_spectrum[:, 1:2]  # [B, 1, W, G]
        b_re, b_im = cur_spectra[:, :, 0], cur_spectra[:, :, 1]  # [B, K, W, G]
        z_re = a_re * b_re + a_im * b_im  # conj(A)·B
        z_im = a_re * b_im - a_im * b_re
        rows = self.inv_rows @ torch.cat([z_re, z_im], dim=-1)  # [B, K, 2N, 2G]
        y_re = rows[..., :n_out, :g] - rows[..., n_out:, g:]  # Σ_f Z e^{+iθ}: cos·Zr − sin·Zi
        y_im = rows[..., :n_out, g:] + rows[..., n_out:, :g]  # cos·Zi + sin·Zr
        return torch.cat([y_re, y_im], dim=-1) @ self.inv_cols  # [B, K, N, N]


# ============================================================================ factored DFT (fast search)
def dft_split(width_px: int) -> tuple[int, int]:
    """(P, Q) with ``P·Q = W``, P a power of two ≤ √W (P = 1: no factorisation possible)."""
    p = 1
    while (2 * p) ** 2 <= width_px and width_px % (2 * p) == 0:
        p *= 2
    return p, width_px // p


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
        th = angles(ip, ip, p)
        s1 = np.stack([np.cos(th), -np.sin(th)], axis=1).reshape(2 * p, p)
        # stage 2, per kr1: rows (kr2, re/im) × (re/im, r2); angle kr2·r2/Q + kr1·r2/W
        s2 = np.zeros((p, q, 2, 2, q))
        for k1 in range(p):
            th = angles(p * iq + k1, iq, w)  # (kr2·P + kr1)·r2
            complex_block(s2[k1], np.cos(th), np.sin(th))
        # stage 3, complex, one matrix: rows (kc1, re/im) × (re/im, c1)
        s3 = np.zeros((p, 2, 2, p))
        th = angles(ip, ip, p)
        complex_block(s3, np.cos(th), np.sin(th))
        # stage 4, per kc1, right-multiplied: (re/im, c2) × (re/im, kc2)
        s4 = np.zeros((p, 2, q, 2, h))
        for k1 in range(p):
            th = angles(iq, p * ih + k1, w)  # c2·(kc2·P + kc1)
            c, s = np.cos(th), np.sin(th)  # [c2, kc2]
            s4[k1, 0, :, 0], s4[k1, 1, :, 0] = c, s  # re' = c·re + s·im
            s4[k1, 0, :, 1], s4[k1, 1, :, 1] = -s, c  # im' = c·im − s·re
        for name, m in (("s1", s1), ("s2", s2.reshape(p, 2 * q, 2 * q)),
                        ("s3", s3.reshape(2 * p, 2 * p)), ("s4", s4.reshape(p, 2 * q, 2 * h))):
            self.register_buffer(name, float32_buffer(m), persistent=False)

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


def complex_block(out: np.ndarray, c: np.ndarray, s: np.ndarray) -> None:
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
        # the natural inverse row matrix with its columns in the factored row order
        self.register_buffer("rows", float32_buffer(inverse_row_matrix(w, n, natural_rows(w))), persistent=False)
        # Y(u, j) = Σ_kc w·[cos θ·(C·Zre − S·Zim) − sin θ·(S·Zre + C·Zim)], θ = 2π·kc·(−j)/W:
        # one matrix over (cos/sin row half, re/im, kc1, kc2) gives the real part directly
        cw, sw = inverse_column_terms(natural_cols(w), -u, w)  # [P, H, N] each
        m = np.stack([np.stack([cw, -sw]), np.stack([-sw, -cw])])  # [cs, ri, P, H, N]
        self.register_buffer("cols", float32_buffer(m.transpose(2, 0, 1, 3, 4).reshape(-1, len(u))),
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


class LowResImage(nn.Module):
    """Natural half spectrum [..., 2, w, w//2+1] → the real image [..., w, w] (matmul iDFT)."""

    def __init__(self, width_px: int):
        super().__init__()
        w = int(width_px)
        cs = forward_row_matrix(w)  # [cos; sin](2π·r·kr/w)
        c, s = cs[:w], cs[w:]
        # rows: complex e^{+iθ}: re' = c·re − s·im, im' = s·re + c·im; one [2w, 2w] matrix
        self.register_buffer("rows", float32_buffer(np.block([[c, -s], [s, c]])), persistent=False)
        # columns: the half-spectrum inverse at every column shift 0..w−1
        self.register_buffer("cols", float32_buffer(half_spectrum_inverse_matrix(w, np.arange(w))),
                             persistent=False)
        self.width_px = w

    def forward(self, spec: torch.Tensor) -> torch.Tensor:
        lead = spec.shape[:-3]
        w = self.width_px
        t = self.rows @ spec.reshape(*lead, 2 * w, -1)  # [.., (ri r), kc]
        t = t.reshape(*lead, 2, w, -1).transpose(-3, -2).reshape(*lead, w, -1)  # [.., r, (ri kc)]
        return t @ self.cols
