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
channel 0 = real, 1 = imaginary part) is the state kept between steps: the spectrum of the
unrotated image. With ``profile.rotation_identity == "exact"`` yaw 0's "rotation" is the image
itself, so the rotated stack's yaw-0 slice spectrum is the next step's state for free; with
``"resampled"`` every yaw is resampled and the state is one more transform (`Rotator`).
Both backends (`FFTCorrelation` here, `MatmulDFTCorrelation` in
``dft.py``) share this state format and the ``spectrum`` / ``correlate`` interface.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from radar_odom.profiles import ROTATION_KERNELS, GridProfile


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


def keys_weights(t: torch.Tensor) -> torch.Tensor:
    """float[..., 4]: Keys' cubic convolution weights (a = −0.5) of the neighbours at offsets
    −1, 0, 1, 2 from a sample at fraction ``t`` ∈ [0, 1) past neighbour 0 (they sum to 1)."""
    a = -0.5
    d = torch.stack([t + 1.0, t, 1.0 - t, 2.0 - t], dim=-1)  # distances, two in [0, 1], two in [1, 2]
    near = ((a + 2.0) * d - (a + 3.0)) * d * d + 1.0
    far = ((a * d - 5.0 * a) * d + 8.0 * a) * d - 4.0 * a
    return torch.where(d <= 1.0, near, far)


def cubic_table(rows: torch.Tensor, cols: torch.Tensor, height: int, width: int):
    """Where samples at pixel positions (rows, cols) read a source [height, width] padded with
    zeros by 2 px before and 3 px after on both axes (`CUBIC_PAD`): (flat index of the neighbour
    at (−1, −1) from the top-left one, int64; row weights [..., 4]; column weights [..., 4]).
    Positions outside clamp into the zero border. `gather_cubic` samples with it."""
    rows = rows.clamp(-1.0, float(height))
    cols = cols.clamp(-1.0, float(width))
    r0, c0 = torch.floor(rows), torch.floor(cols)
    index = ((r0 + 1.0) * (width + 5) + (c0 + 1.0)).to(torch.int64)
    return index, keys_weights(rows - r0), keys_weights(cols - c0)


CUBIC_PAD = (2, 3, 2, 3)  # F.pad of the source for `cubic_table`: 2 before, 3 after, both axes


def gather_cubic(flat: torch.Tensor, index: torch.Tensor, wr: torch.Tensor, wc: torch.Tensor,
                 stride: int) -> torch.Tensor:
    """Cubic samples of ``flat`` [N, L] (rows of ``stride`` values) from a `cubic_table`:
    sixteen ``GatherElements`` weighted by row and column weights [..., M, 4] (broadcast against
    [N, M]). Interpolating (it passes through the pixels), so a sample on a pixel is that pixel,
    and its blur between pixels is far less phase-dependent than the bilinear one's."""
    out = None
    for i in range(4):
        row = None
        for j in range(4):
            at = torch.gather(flat, 1, index + (i * stride + j)) * wc[..., j]
            row = at if row is None else row + at
        term = row * wr[..., i]
        out = term if out is None else out + term
    return out


# The polar grid each kernel resamples onto: (rows per yaw step, radial step in px). The bilinear
# grid is oversampled so that its round trip blurs little; the cubic kernel keeps that detail on a
# grid of one row per yaw step and one radius per pixel, which also reads small turns more fully
# (cart-0.4 on the seed-5150 curve: 0.58 of the turn on the finer grid, 0.63 on this one; shared
# RADIATE drive, graph alone: 3.79 → 3.39 %) and costs a quarter of the samples (the step 0.98–1.09×
# the previous bilinear graph's time, against 1.43× for cubic on the finer grid; compare_graphs.py).
POLAR_GRIDS = {"bilinear": (2, 0.5), "cubic": (1, 1.0)}


def polar_rotator(width_px: int, step_rad: float, radius_px: float, max_shift: int, kernel: str) -> PolarRotator:
    """The `PolarRotator` a profile's ``rotation_kernel`` uses, on that kernel's grid (`POLAR_GRIDS`)."""
    if kernel not in POLAR_GRIDS:
        raise ValueError(f"rotation kernel {kernel!r}: choose one of {tuple(POLAR_GRIDS)}")
    oversample, radial_step_px = POLAR_GRIDS[kernel]
    return PolarRotator(width_px, step_rad, radius_px, max_shift, oversample=oversample,
                        radial_step_px=radial_step_px, kernel=kernel)


def divides_turn(step_rad: float) -> bool:
    """Whether a whole number of rotation steps (rad) makes the full turn: what `PolarRotator`
    (rotation by whole rows of a polar image) needs."""
    steps = 2 * math.pi / step_rad
    return abs(steps - round(steps)) <= 1e-6


class PolarRotator(nn.Module):
    """Rotate images by whole yaw steps through one shared polar resampling.

    Rotating about the image centre is a shift along azimuth in polar coordinates. The image
    is resampled once onto a polar grid (``oversample`` rows per yaw step, a radius every
    ``radial_step_px`` up to ``radius_px``; oversampling keeps the round trip's blur small and
    alike for every rotation); rotation by s steps is a roll of that grid, and each rotated image
    is resampled back to Cartesian with one table shared by all rotations. The tables depend
    only on the geometry: they are computed in the graph from a few constants and folded by
    onnxruntime at session start, so the file stays small. Both resamplings are bilinear with
    zeros outside; the result differs from direct bilinear rotation (`correlation.rotate_images`) by the
    second interpolation, a slight blur (the accuracy is measured in benchmarks/).

    Layout (for speed in onnxruntime; the numbers are those of rolling and zero-padding the
    polar grid): the first resampling writes the *wrapped, padded* grid ``[A + 2m + 1, R + 3]``
    directly (row ``m + j`` is azimuth j, wrapped, for j = −m..A + m; column 0 and the last two
    are the zero padding the second resampling's border needs, read from the source's zero
    border), and the second one reads every rotation from that one grid: the roll is a row
    offset folded into a constant table (`rotate_constant`), added to the index (`forward`,
    any shifts) or, for consecutive shifts (`rotate_band`, the fast step's band), the start of
    one block of whole rows, the tables staying constant. No rolled copies, no ``Pad``/``Concat``.
    """

    def __init__(self, width_px: int, step_rad: float, radius_px: float, max_shift: int,
                 oversample: int = 2, radial_step_px: float = 0.5, kernel: str = "bilinear"):
        super().__init__()
        if kernel not in ROTATION_KERNELS:
            raise ValueError(f"kernel={kernel!r}: choose one of {ROTATION_KERNELS}")
        self.kernel = kernel  # of the first resampling (image → polar grid); the second is bilinear
        steps = 2 * math.pi / step_rad
        if not divides_turn(step_rad):
            raise ValueError(f"rotation step {step_rad} rad does not divide the full turn; "
                             "use rotation='bilinear'")
        self.width_px = int(width_px)
        self.oversample = int(oversample)  # polar rows per yaw step
        self.azimuths = int(round(steps)) * self.oversample
        self.bin_rad = float(step_rad) / self.oversample
        self.radial_step_px = float(radial_step_px)
        self.radii = int(math.ceil(radius_px / self.radial_step_px)) + 2
        self.max_shift = int(max_shift) * self.oversample  # in polar rows
        # The second resampling reads zeros (the grid's padding columns) at every pixel at least
        # ``radii`` radial steps from the centre: only the square around that disc is sampled and
        # the rest padded with zeros (`_place`), the same numbers at 0.75x the samples (0.4 m/px).
        c_w = (self.width_px - 1) / 2
        reach = self.radii * self.radial_step_px
        lo = max(0, int(math.floor(c_w - reach)))
        self.crop = (lo, self.width_px - 2 * lo)  # (first row/column sampled, rows/columns sampled)

    def _tables(self, dtype):
        """(the first resampling's table onto the wrapped padded grid, the second's (Cartesian
        pixels' azimuth row, radius column) [size²] over the ``crop`` square)."""
        w, a, r, m = self.width_px, self.azimuths, self.radii, self.max_shift
        c_w = (w - 1) / 2
        # wrapped rows: azimuth bins A − m..A − 1, 0..A − 1, 0..m (torch.cat of the bins' angles)
        bins = torch.arange(a, dtype=dtype)
        phi = torch.cat([bins[a - m:], bins, bins[: m + 1]]) * self.bin_rad
        rho = torch.arange(r, dtype=dtype) * self.radial_step_px
        # polar sample (rho, phi) sits at x = rho·cos φ (up the rows), y = rho·sin φ (columns)
        rows = c_w - rho[None, :] * torch.cos(phi)[:, None]
        cols = c_w + rho[None, :] * torch.sin(phi)[:, None]
        # padding columns: a position past the far corner clamps onto the source's zero border
        # (fractions 0), so they sample exactly 0
        far = torch.full((phi.shape[0], 1), 2.0 * w, dtype=dtype)
        rows = torch.cat([far, rows, far, far], dim=1)
        cols = torch.cat([far, cols, far, far], dim=1)
        to_polar = (cubic_table if self.kernel == "cubic" else bilinear_table)(rows, cols, w, w)
        idx = torch.arange(w, dtype=dtype)
        x = (c_w - idx)[:, None].expand(w, w)
        y = (idx - c_w)[None, :].expand(w, w)
        az = torch.atan2(y, x)
        az = torch.where(az < 0, az + 2 * math.pi, az) / self.bin_rad
        rho = torch.sqrt(x * x + y * y) / self.radial_step_px
        lo, size = self.crop  # cut after the maths: the very floats of the whole image's tables
        return to_polar, (az[lo:lo + size, lo:lo + size].reshape(-1), rho[lo:lo + size, lo:lo + size].reshape(-1))

    def _place(self, samples: torch.Tensor, b: int, k: int) -> torch.Tensor:
        """Samples of the cropped square [B, K·size²] → images [B, K, W, W], zero outside the square
        (where the second resampling reads only zeros: ``crop``)."""
        lo, size = self.crop
        out = samples.reshape(b, k, size, size)
        hi = self.width_px - lo - size
        return F.pad(out, (lo, hi, lo, hi)) if lo or hi else out

    def _wrapped_polar(self, images: torch.Tensor):
        """images [B, W, W] → the wrapped padded polar grid flattened [B, (A + 2m + 1)·(R + 3)]
        (class docstring), the second resampling's table (`bilinear_table` on the padded
        rolled grid [A + 1, R]: index int64[W·W], fractions float[W·W]) and the Cartesian
        pixels' (azimuth row, radius column) it was made from (for `_constant_table`)."""
        a = self.azimuths
        to_polar, (az, rho) = self._tables(images.dtype)
        b, w = images.shape[0], self.width_px
        index, fr, fc = to_polar
        if self.kernel == "cubic":
            flat = F.pad(images, CUBIC_PAD).reshape(b, -1)
            wrapped = gather_cubic(flat, index.reshape(1, -1).expand(b, -1), fr.reshape(1, -1, 4),
                                   fc.reshape(1, -1, 4), w + 5)
        else:
            flat = F.pad(images, (1, 2, 1, 2)).reshape(b, -1)
            wrapped = gather_lerp(flat, index.reshape(1, -1).expand(b, -1), fr.reshape(1, -1),
                                  fc.reshape(1, -1), w + 3, source_differences=True)
        return wrapped, bilinear_table(az, rho, a + 1, self.radii), (az, rho)

    def _rotate(self, wrapped: torch.Tensor, index: torch.Tensor, fr: torch.Tensor, fc: torch.Tensor):
        """Samples of the wrapped grid [B, L] at a table on it (index int64[B or 1, M] into the
        grid *with* a zero row before it, as `bilinear_table` gives, fractions [1, M]) → [B, M]."""
        stride = self.radii + 3
        index = index - stride  # no zero row before the wrapped grid: it is never read
        if index.shape[0] != wrapped.shape[0]:
            index = index.expand(wrapped.shape[0], -1)
        return gather_lerp(wrapped, index, fr, fc, stride)

    def forward(self, images: torch.Tensor, shifts: torch.Tensor) -> torch.Tensor:
        """images [B, W, W], shifts int64[B, K] (yaw = shift·step) → [B, K, W, W]."""
        b, k = shifts.shape
        wrapped, (index, fr, fc), _ = self._wrapped_polar(images)
        # rotation by s reads the rolled grid whose row j is wrapped row m − oversample·s + j:
        # the (data-dependent) roll is a row offset added to the shared table's index
        rows = (self.max_shift - self.oversample * shifts) * (self.radii + 3)  # [B, K]
        index = (index.reshape(1, 1, -1) + rows.unsqueeze(-1)).reshape(b, -1)
        out = self._rotate(wrapped, index, fr.reshape(1, -1).repeat(1, k), fc.reshape(1, -1).repeat(1, k))
        return self._place(out, b, k)

    def rotate_band(self, images: torch.Tensor, last_shift: torch.Tensor, count: int,
                    with_zero: bool = False) -> torch.Tensor:
        """images [B, W, W] rotated by the ``count`` consecutive shifts ending at ``last_shift``
        int64[B] (``last_shift − count + 1 .. last_shift``) → [B, count, W, W]; equal to
        ``forward`` with those shifts. ``with_zero``: one more slice at the end, the round trip
        at shift 0 (`rotate_constant` with ``[0]``), from the same polar grid.

        The data-dependent roll is one row ``Gather`` (a contiguous block of the wrapped grid,
        whole rows) and every bilinear table is constant (folded at session start), so no index
        arithmetic runs per sweep.
        """
        b, r = images.shape[0], self.radii
        stride, o = r + 3, self.oversample
        rows = self.azimuths + o * (count - 1) + 1  # the block's rows that the band reads
        wrapped, (index, fr, fc), (az, rho) = self._wrapped_polar(images)
        total = wrapped.shape[1] // stride
        # band item j (shift last − (count − 1 − j)) reads wrapped rows from
        # m − o·last + o·(count − 1 − j) on: the block starts at first = m − o·last (0..2m, so
        # the block's last row, first + o·(count − 1) + A, is at most A + 2m: inside)
        first = self.max_shift - o * last_shift  # [B]
        pick = first.reshape(b, 1) + torch.arange(rows, device=images.device)
        pick = pick + torch.arange(b, device=images.device).reshape(b, 1) * total
        block = wrapped.reshape(-1, stride).index_select(0, pick.reshape(-1)).reshape(b, -1)
        offsets = o * (count - 1 - torch.arange(count, device=images.device)) * stride  # [count]
        index = (index.reshape(1, -1) + offsets.reshape(-1, 1)).reshape(1, -1)
        out = self._rotate(block, index, fr.reshape(1, -1).repeat(1, count), fc.reshape(1, -1).repeat(1, count))
        if with_zero:  # one more slice: the round trip at shift 0, from the whole grid
            zero = self._rotate(wrapped, *self._constant_table([0], az, rho))
            out = torch.cat([out.reshape(b, count, -1), zero.reshape(b, 1, -1)], dim=1)
            count += 1
        return self._place(out, b, count)

    def rotate_constant(self, images: torch.Tensor, shifts) -> torch.Tensor:
        """images [B, W, W] rotated by fixed shifts (a list of ints) → [B, K, W, W].

        With fixed shifts the roll folds into the sampling table (constant, folded at session
        start).
        """
        wrapped, _, (az, rho) = self._wrapped_polar(images)
        out = self._rotate(wrapped, *self._constant_table(shifts, az, rho))
        return self._place(out, images.shape[0], len(shifts))

    def _constant_table(self, shifts, az, rho):
        """The second resampling's table on the whole wrapped grid for fixed shifts (ints), from
        the Cartesian pixels' (azimuth row, radius column) ``az``, ``rho`` (`_wrapped_polar`):
        (index int64[1, K·W·W], row and column fractions [1, K·W·W]), as `_rotate` takes it."""
        m, r = self.max_shift, self.radii
        offsets = torch.tensor([m - self.oversample * int(s) for s in shifts], dtype=az.dtype)
        index, fr, fc = bilinear_table(az.reshape(1, -1) + offsets.reshape(-1, 1),
                                        rho.reshape(1, -1).expand(len(shifts), -1),
                                        self.azimuths + 2 * m + 1, r)
        return index.reshape(1, -1), fr.reshape(1, -1), fc.reshape(1, -1)


class Rotator(nn.Module):
    """Rotates feature images by every yaw candidate.

    ``profile.rotation_identity``:

    * ``"exact"``: bilinear ``grid_sample`` with precomputed grids, and yaw 0 is not sampled: its
      slice is the input itself (so the stream state taken from it equals the unrotated
      spectrum bit for bit, one ``grid_sample`` cheaper). Every other yaw is an interpolated,
      slightly blurred copy, so yaw 0 is favoured (`GridProfile.rotation_identity`).
    * ``"resampled"``: every yaw, 0 included, through the polar round trip of `PolarRotator`
      (the fast search's rotation), so that all candidates are blurred alike and training sees
      the very volume the exported fast search computes.

    ``exact_identity`` says whether the yaw-0 slice (index ``zero_index``) is the input itself.
    """

    def __init__(self, profile: GridProfile):
        super().__init__()
        yaws = list(profile.rotations_rad)
        self.zero_index = yaws.index(0.0)
        self.exact_identity = profile.rotation_identity == "exact"
        self.polar = None
        if not self.exact_identity:
            # features are zero beyond the support disc (model.support_disc): rotate only that
            disc_px = (profile.width_px - 1) / 2 - profile.translation_cells
            self.polar = polar_rotator(profile.width_px, profile.rotation_step_rad, disc_px, self.zero_index,
                                       profile.rotation_kernel)
            self.shifts = [k - self.zero_index for k in range(len(yaws))]
        others = torch.tensor([y for y in yaws if y != 0.0], dtype=torch.float64)
        if self.exact_identity:
            grids = rotation_grids(others, profile.width_px).to(torch.float32)
            self.register_buffer("grids", grids, persistent=False)
        self.rotates = len(others) > 0  # a plain bool: export tracing sees no shape test

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """float[B, W, W] → float[B, K, W, W] in the order of ``profile.rotations_rad``."""
        if not self.rotates:  # a rotation-free profile: yaw 0 is the only candidate
            return images.unsqueeze(1)
        if self.polar is not None:
            return self.polar.rotate_constant(images, self.shifts)
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
