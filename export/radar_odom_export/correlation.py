"""Correlative scan matching (paper Alg. 2): pose candidates, rotation, FFT correlation volume.

Geometry (the contract shared with export and runtime). Feature images ``S`` are float[B, W, W]
in the Cartesian convention: row 0 is furthest ahead (+x), columns grow towards +y, and pixel
(r, c) sits at metric ``x = (cW − r)·res, y = (c − cW)·res`` with ``cW = (W − 1)/2``.

Candidates are ``yaw_k ∈ profile.rotations_rad`` (K) and translations ``(i·res, j·res)`` for
``i, j ∈ [−n, n]`` (N = 2n + 1). The volume ``C`` is float[B, K, N, N], axis 2 ↔ ``i + n``
(x), axis 3 ↔ ``j + n`` (y), with

    C[k, i, j] = Σ_q S_prev(q) · S_cur(R(yaw_k)ᵀ (q − t_ij))

over the metric pixel positions q of the previous image: the current sweep is warped into the
previous frame with the candidate pose (Oxford convention: pose of the later frame in the
earlier one) and dotted with the previous image. With ``Rot_k(p) = S_cur(R(yaw_k)ᵀ p)``, and
since ``q − t_ij`` moves pixel (r, c) to (r + i, c − j) (row ↔ −x), this is

    C[k, i, j] = Σ_{r,c} S_prev[r, c] · Rot_k[r + i, c − j] = X_k(u = i, v = −j),
    X_k = IDFT2(conj(DFT2(S_prev)) · DFT2(Rot_k)).

The DFT makes the correlation circular: a shift by (u, v) pairs the |u| rows / |v| columns at
one border with those at the opposite border. Radar power fades with range, the learned mask
can suppress the border bands, and the raw-scan baseline accepts that small bias, exactly as an
FFT implementation of the paper does; a linear correlation would need DFT length W + n.

Streaming: a sweep's *spectrum* (half spectrum along columns, float[..., 2, W, W//2 + 1] with
channel 0 = real, 1 = imaginary part) is the state kept between steps. Yaw 0 is always a
candidate and its "rotation" is the image itself, so the rotated stack's yaw-0 slice spectrum is
the next step's state for free. Both backends (`FFTCorrelation` here, `MatmulDFTCorrelation` in
``dft.py``) share this state format and the ``spectrum`` / ``correlate`` interface.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import GridProfile


def translation_offsets(profile: GridProfile) -> torch.Tensor:
    """int64[N]: the searched pixel offsets −n..n (the same list for x rows and y columns)."""
    n = profile.translation_cells
    return torch.arange(-n, n + 1)


def candidate_poses(profile: GridProfile, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """float[K, N, N, 3] pose candidates (x m, y m, yaw rad) matching the volume's layout.

    ``out[k, i + n, j + n] = (i·res, j·res, yaw_k)``: the later sweep's pose in the earlier
    sweep's frame (Oxford convention) that the volume entry ``C[:, k, i + n, j + n]`` scores.
    """
    offsets_m = translation_offsets(profile).to(torch.float64) * profile.resolution_m
    yaws = torch.tensor(profile.rotations_rad, dtype=torch.float64)
    k, n = len(yaws), len(offsets_m)
    out = torch.empty(k, n, n, 3, dtype=torch.float64)
    out[..., 0] = offsets_m[None, :, None]
    out[..., 1] = offsets_m[None, None, :]
    out[..., 2] = yaws[:, None, None]
    return out.to(dtype)


def rotation_grids(yaws_rad: torch.Tensor, width_px: int) -> torch.Tensor:
    """float[K, W, W, 2] ``grid_sample`` grids (align_corners=True) that rotate images by yaws.

    Output pixel p (metric) samples the input at ``R(yaw)ᵀ p``, so the result is the image of
    the current sweep seen from a frame rotated by ``yaw`` (Oxford convention, positive yaw
    turns +x towards +y). Rotation is about the image centre (metric origin). Written with
    plain tensor ops (no ``affine_grid``) so an exporter may also compute it inside a graph.
    With align_corners=True the normalised coordinate −1/+1 is the centre of the first/last
    pixel, i.e. ``g = (index − cW)/cW``, the same affine map on both axes.
    """
    yaws = torch.as_tensor(yaws_rad)
    dtype = yaws.dtype if yaws.is_floating_point() else torch.float32
    yaws = yaws.to(dtype)
    c_w = (width_px - 1) / 2
    idx = torch.arange(width_px, dtype=dtype)
    # normalised metric coordinates of output pixel centres: x up the rows, y along columns
    x_n = ((c_w - idx) / c_w)[:, None].expand(width_px, width_px)  # [W, W], by row
    y_n = ((idx - c_w) / c_w)[None, :].expand(width_px, width_px)  # [W, W], by column
    cos, sin = torch.cos(yaws)[:, None, None], torch.sin(yaws)[:, None, None]
    src_x = cos * x_n + sin * y_n  # R(yaw)ᵀ p
    src_y = -sin * x_n + cos * y_n
    # grid_sample wants (column, row) order; row index grows towards −x
    return torch.stack([src_y, -src_x], dim=-1)


def rotate_images(images: torch.Tensor, grids: torch.Tensor) -> torch.Tensor:
    """float[B, K, W, W]: each of B images [B, W, W] rotated by K grids (`rotation_grids`).

    ``grids``: [K, W, W, 2], the same K rotations for every image, or [B, K, W, W, 2], K of its
    own for each image (the fast search's per-item yaw bands). Bilinear, zeros outside the image.
    Shared grids ride the batch in the channel axis, so one ``grid_sample`` call (K grids, B
    channels) does all B·K rotations.
    """
    if grids.dim() == 5:
        b, k, w = grids.shape[0], grids.shape[1], images.shape[-1]
        stack = images.unsqueeze(1).expand(b, k, w, w).reshape(b * k, 1, w, w)
        rotated = F.grid_sample(stack, grids.reshape(b * k, *grids.shape[2:]), mode="bilinear",
                                padding_mode="zeros", align_corners=True)
        return rotated.reshape(b, k, w, w)
    k = grids.shape[0]
    stack = images.unsqueeze(0).expand(k, *images.shape)  # [K, B, W, W], no copy
    rotated = F.grid_sample(stack, grids, mode="bilinear", padding_mode="zeros",
                            align_corners=True)
    return rotated.transpose(0, 1)


def bilinear_table(rows: torch.Tensor, cols: torch.Tensor, height: int, width: int):
    """Where samples at pixel positions (rows, cols) read a source [height, width] padded with
    zeros by 1 px before and 2 px after on both axes: (flat index of the top-left neighbour
    int64, row fraction, column fraction). Positions outside clamp into the zero border.

    Written with plain tensor ops so that, on constant positions, the exporter or onnxruntime
    folds the table (the file stays small); `gather_lerp` samples with it.
    """
    rows = rows.clamp(-1.0, float(height))
    cols = cols.clamp(-1.0, float(width))
    r0, c0 = torch.floor(rows), torch.floor(cols)
    index = ((r0 + 1.0) * (width + 3) + (c0 + 1.0)).to(torch.int64)
    return index, rows - r0, cols - c0


def gather_lerp(flat: torch.Tensor, index: torch.Tensor, fr: torch.Tensor, fc: torch.Tensor,
                stride: int, source_differences: bool = False) -> torch.Tensor:
    """Bilinear samples of ``flat`` [N, L] (rows of ``stride`` values, row-major) whose top-left
    neighbours are at ``index`` int64[N, M], with row and column fractions fr, fc (broadcast
    against [N, M]): four ``GatherElements`` and the two-level lerp. In onnxruntime this is the
    cheapest bilinear sampler measured: ``GridSample`` runs on one thread (~70 ns a sample), and a
    ``Gather`` of packed neighbours (one op instead of four) is 2–6× slower.

    ``source_differences``: take the column neighbours' differences on the source (L values)
    and gather them, instead of subtracting gathered pairs (M values each): the same floats,
    two full-size subtractions fewer, worth it when the samples outnumber the source pixels.
    """
    def at(source, offset):
        return torch.gather(source, 1, index + offset if offset else index)

    if source_differences:
        diff = flat[:, 1:] - flat[:, :-1]  # diff[i] = flat[i + 1] − flat[i]
        top = at(flat, 0) + fc * at(diff, 0)
        bottom = at(flat, stride) + fc * at(diff, stride)
    else:
        top = at(flat, 0)
        top = top + fc * (at(flat, 1) - top)
        bottom = at(flat, stride)
        bottom = bottom + fc * (at(flat, stride + 1) - bottom)
    return top + fr * (bottom - top)


class Rotator(nn.Module):
    """Rotates feature images by every yaw candidate with precomputed sampling grids.

    Yaw 0 is not sampled: its slice is the input itself, exactly (so the stream state taken
    from it equals the unrotated spectrum bit for bit) and one ``grid_sample`` cheaper.
    """

    def __init__(self, profile: GridProfile):
        super().__init__()
        yaws = list(profile.rotations_rad)
        self.zero_index = yaws.index(0.0)
        others = torch.tensor([y for y in yaws if y != 0.0], dtype=torch.float64)
        grids = rotation_grids(others, profile.width_px).to(torch.float32)
        self.register_buffer("grids", grids, persistent=False)
        self.rotates = len(others) > 0  # a plain bool: export tracing sees no shape test

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """float[B, W, W] → float[B, K, W, W] in the order of ``profile.rotations_rad``."""
        if not self.rotates:  # a rotation-free profile: yaw 0 is the only candidate
            return images.unsqueeze(1)
        rotated = rotate_images(images, self.grids)
        z = self.zero_index
        return torch.cat([rotated[:, :z], images.unsqueeze(1), rotated[:, z:]], dim=1)


class FFTCorrelation(nn.Module):
    """Correlation volume with ``torch.fft`` (training speed). See the module docstring."""

    def __init__(self, width_px: int, translation_cells: int):
        super().__init__()
        self.width_px = width_px
        self.translation_cells = translation_cells

    def spectrum(self, images: torch.Tensor) -> torch.Tensor:
        """float[..., W, W] → half spectrum float[..., 2, W, W//2 + 1] (re, im)."""
        spec = torch.fft.rfft2(images)
        return torch.stack([spec.real, spec.imag], dim=-3)

    def correlate(self, prev_spectrum: torch.Tensor, cur_spectra: torch.Tensor) -> torch.Tensor:
        """Volume float[B, K, N, N] from prev [B, 2, W, G] and rotated current [B, K, 2, W, G]."""
        prev = torch.complex(prev_spectrum[:, 0], prev_spectrum[:, 1]).unsqueeze(1)
        cur = torch.complex(cur_spectra[:, :, 0], cur_spectra[:, :, 1])
        full = torch.fft.irfft2(prev.conj() * cur, s=(self.width_px, self.width_px))
        n = self.translation_cells
        # rows u = i = −n..n; columns v = −j for j = −n..n, i.e. v = n..−n (hence the flip)
        window = full.roll(shifts=(n, n), dims=(-2, -1))[..., : 2 * n + 1, : 2 * n + 1]
        return window.flip(-1)


CORRELATION_KINDS = ("fft", "matmul")


def make_correlation(kind: str, width_px: int, translation_cells: int) -> nn.Module:
    """The correlation backend ``kind`` ("fft" or "matmul"); both share one interface."""
    if kind == "fft":
        return FFTCorrelation(width_px, translation_cells)
    if kind == "matmul":
        from .dft import MatmulDFTCorrelation

        return MatmulDFTCorrelation(width_px, translation_cells)
    raise ValueError(f"dft={kind!r} is not a correlation backend; "
                     f"choose one of {CORRELATION_KINDS}")
