"""Matmul-DFT correlation: the export backend, with the same interface as `FFTCorrelation`.

The ONNX ``DFT`` op runs only on onnxruntime's CPU provider and complex tensors do not export,
so here every transform is a real matmul with constant cos/sin matrices (built in float64,
stored float32) on separate real and imaginary parts:

* forward (``spectrum``): real-input half spectrum along columns (W//2 + 1 frequencies, one
  ``[W, 2G]`` matmul giving re and im at once), then the full complex DFT along rows (one
  ``[2W, W]`` matmul whose two halves combine into re and im);
* cross-power ``conj(prev) · cur`` elementwise on (re, im) pairs;
* windowed inverse (``correlate``): only the N = 2n + 1 candidate shifts per axis are computed,
  with ``[2N, W]`` and ``[2G, N]`` matrices instead of a full inverse. The half spectrum is
  summed with Hermitian weights (1 at g = 0 and, for even W, at g = W/2; 2 elsewhere) and only
  the real part is kept, which is exact because the full-spectrum sum is real.

Conventions (sign, layout, circularity) are those of ``correlation.py``'s module docstring.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn


def half_spectrum_size(width_px: int) -> int:
    """G: frequencies kept along the real-input (column) axis."""
    return width_px // 2 + 1


def forward_column_matrix(width_px: int) -> np.ndarray:
    """float64[W, 2G]: ``S @ M = [Re | Im]`` of the DFT of each row of S over columns (g ≤ W/2).

    ``M[c, g] = cos(2π c g / W)`` and ``M[c, G + g] = −sin(2π c g / W)`` (forward sign e^{−iθ}).
    """
    c = np.arange(width_px)[:, None]
    g = np.arange(half_spectrum_size(width_px))[None, :]
    theta = 2 * np.pi * ((c * g) % width_px) / width_px  # reduce mod W first: exact angles
    return np.concatenate([np.cos(theta), -np.sin(theta)], axis=1)


def forward_row_matrix(width_px: int) -> np.ndarray:
    """float64[2W, W]: ``[cos; sin](2π f r / W)``; ``M @ P`` gives the four real products
    from which the complex row DFT ``(cos − i·sin) @ (P_re + i·P_im)`` is assembled."""
    f = np.arange(width_px)[:, None]
    r = np.arange(width_px)[None, :]
    theta = 2 * np.pi * ((f * r) % width_px) / width_px
    return np.concatenate([np.cos(theta), np.sin(theta)], axis=0)


def inverse_row_matrix(width_px: int, translation_cells: int) -> np.ndarray:
    """float64[2N, W]: ``[cos; sin](2π f u / W)`` for the row shifts u = −n..n only."""
    n = translation_cells
    u = np.arange(-n, n + 1)[:, None]
    f = np.arange(width_px)[None, :]
    theta = 2 * np.pi * ((u * f) % width_px) / width_px
    return np.concatenate([np.cos(theta), np.sin(theta)], axis=0)


def inverse_column_matrix(width_px: int, translation_cells: int) -> np.ndarray:
    """float64[2G, N]: ``[Y_re | Y_im] @ M`` is the real windowed inverse over columns.

    Output column ``j + n`` (j = −n..n) is the shift v = −j (volume axis 3 grows with +y while
    the correlation shift grows with columns of the *current* image, see correlation.py).
    ``M[g, ·] = w_g·cos(2π g v / W) / W²``, ``M[G + g, ·] = −w_g·sin(2π g v / W) / W²``, with
    Hermitian weights w_g and the full 1/W² normalisation of the 2-D inverse.
    """
    n = translation_cells
    g_count = half_spectrum_size(width_px)
    g = np.arange(g_count)[:, None]
    v = -np.arange(-n, n + 1)[None, :]
    weights = np.full((g_count, 1), 2.0)
    weights[0] = 1.0
    if width_px % 2 == 0:
        weights[-1] = 1.0  # the Nyquist column has no mirror partner
    theta = 2 * np.pi * ((g * v) % width_px) / width_px
    scale = weights / float(width_px) ** 2
    return np.concatenate([scale * np.cos(theta), -scale * np.sin(theta)], axis=0)


def _buffer(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(a.astype(np.float32))


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
            self.register_buffer(name, _buffer(matrix), persistent=False)

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
