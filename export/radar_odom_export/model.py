"""`MaskedCorrelator`: mask → masked image → rotate ×K → correlate → soft-argmax (paper Alg. 1).

One module holds the whole differentiable pipeline for training and export:

* masking ``"learned"``: the U-Net predicts ``M`` and the features are ``S = M ⊙ Z``;
  ``"raw"``: ``M ≡ 1`` (the raw-scan baseline, no parameters); ``"cfar"``: a classical
  cell-averaging CFAR mask (`cfar.CFARMask`, no parameters: for a new radar without ground
  truth); ``"external"``: the caller passes the masks (e.g. the simulator's static labels, or
  masks from another network).
* ``profile.input_norm`` ``"floor-scale"``: each sweep is normalised first (`normalise`:
  range-dependent floor removed, divided by a robust per-sweep scale), and ``Z`` above is the
  normalised sweep everywhere: the masker's input and the features ``S = M ⊙ Z_n``. Public
  methods take raw sweeps and normalise them once. ``"none"``: the sweep as it is.
* ``profile.mode`` ``"single"`` masks each sweep alone, ``"dual"`` stacks both sweeps into a
  2-channel U-Net input and gets both masks at once.
* ``profile.input_kind`` ``"cartesian"``: sweeps are Cartesian images float[B, W, W];
  ``"polar"``: sweeps are range-reduced polar images float[B, A, B'] (see `PolarToCartesian`),
  masked in polar and turned into Cartesian features inside the model.
* ``dft`` ``"fft"`` (training) or ``"matmul"`` (export); the same volume either way.

Poses are the later sweep's pose in the earlier sweep's frame (Oxford convention), as
``(x m, y m, yaw rad)``; the covariance is 3×3 over the same. Constant grids and DFT matrices
are non-persistent buffers, so ``state_dict`` holds only the U-Net weights.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from radar_odom.polar import cartesian_sample_maps, near_range_bins
from radar_odom.profiles import GridProfile

from .cfar import make_cfar
from .correlation import Rotator, candidate_poses, make_correlation
from .normalise import make_normaliser
from .softargmax import candidate_weights, read_pose, weighted_covariance
from .unet import UNet

MASKINGS = ("learned", "raw", "cfar", "external")

# The Navtech CTS350-X as recorded in Oxford Radar RobotCar (and simulated by default): the
# sweep geometry a polar model is built for unless told otherwise. Keys as `RadarScan.geometry`.
CTS350X_GEOMETRY = {
    "num_azimuths": 400,
    "num_bins": 3768,
    "range_resolution_m": 0.0432,
    "range_offset_m": 0.0,
}


class PolarToCartesian(nn.Module):
    """Range-reduced polar images float[B, A, B'] → Cartesian float[B, W, W], in the model.

    The range axis is reduced before the masker so that the polar U-Net costs about as much as
    the Cartesian one: ``bin_factor = round(resolution_m / range_resolution_m)`` consecutive
    bins are averaged (0.4 m/px on a 0.0432 m radar: 9 bins → 0.389 m cells) and only the
    ``num_bins`` reduced bins that reach the image corners are kept. The caller reduces
    (``power[:, :num_bins·bin_factor].reshape(A, num_bins, bin_factor).mean(-1)``, as the
    runtime does), so the graph input stays small.

    Azimuths are assumed uniform, row a at ``2π·a/A`` (the sweep's rows rolled so that row 0
    is the one nearest 0 rad). The sampling grid is `radar_odom.polar.cartesian_sample_maps`
    on the reduced geometry, turned into a ``grid_sample`` grid on the seam-padded image, so
    the mapping is `polar_to_cartesian`'s (bilinear, seam interpolated, zero beyond the last
    bin). Reduced bins whose centre lies closer than ``profile.near_range_m`` are zeroed (the
    vehicle's own returns), like the Cartesian path's near-range blanking.
    """

    def __init__(self, profile: GridProfile, sweep_geometry: dict):
        super().__init__()
        rr = float(sweep_geometry["range_resolution_m"])
        offset = float(sweep_geometry["range_offset_m"])
        self.num_azimuths = int(sweep_geometry["num_azimuths"])
        self.bin_factor = max(1, int(round(profile.resolution_m / rr)))
        reduced_rr = self.reduced_rr = rr * self.bin_factor
        self.offset_m = offset
        azimuths = 2 * np.pi * np.arange(self.num_azimuths) / self.num_azimuths
        available = int(sweep_geometry["num_bins"]) // self.bin_factor
        map_bin, _ = cartesian_sample_maps(azimuths, available, reduced_rr, offset,
                                           profile.resolution_m, profile.width_px)
        # bilinear sampling at u reads bins floor(u) and floor(u) + 1: keep exactly those
        self.num_bins = int(min(available, math.floor(float(map_bin.max())) + 2))
        map_bin, map_row = cartesian_sample_maps(azimuths, self.num_bins, reduced_rr, offset,
                                                 profile.resolution_m, profile.width_px)
        # align_corners=True: −1/+1 are the centres of the first/last bin and padded row
        grid = np.stack([2 * map_bin / max(self.num_bins - 1, 1) - 1,
                         2 * map_row / (self.num_azimuths + 1) - 1], axis=-1)
        self.register_buffer("grid", torch.from_numpy(grid.astype(np.float32))[None],
                             persistent=False)
        keep = torch.ones(self.num_bins)
        keep[: near_range_bins(profile.near_range_m, reduced_rr, offset, self.num_bins)] = 0.0
        self.register_buffer("near_keep", keep, persistent=False)

    @property
    def input_shape(self) -> tuple[int, int]:
        """(A, B'): one reduced polar sweep as the model takes it."""
        return self.num_azimuths, self.num_bins

    def forward(self, polar: torch.Tensor) -> torch.Tensor:
        """float[B, A, B'] → float[B, W, W] (Cartesian convention, see correlation.py)."""
        polar = polar * self.near_keep
        padded = torch.cat([polar[:, -1:], polar, polar[:, :1]], dim=1)  # seam rows
        grid = self.grid.expand(polar.shape[0], *self.grid.shape[1:])
        return nn.functional.grid_sample(padded.unsqueeze(1), grid, mode="bilinear",
                                         padding_mode="zeros", align_corners=True).squeeze(1)


def gaussian_kernel_1d(sigma_px: float) -> torch.Tensor:
    """float32[2r + 1] normalised Gaussian taps of ``sigma_px`` (r = ⌈3σ⌉); [1.0] for σ = 0."""
    if sigma_px <= 0:
        return torch.ones(1)
    r = int(math.ceil(3 * sigma_px))
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    k = torch.exp(-0.5 * (x / sigma_px) ** 2)
    return (k / k.sum()).to(torch.float32)


def blur_images(images: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """images float[B, H, W] convolved with the separable kernel ``taps`` ⊗ ``taps`` (zero outside)."""
    r = taps.numel() // 2
    x = images.unsqueeze(1)
    x = nn.functional.conv2d(x, taps.view(1, 1, 1, -1), padding=(0, r))
    x = nn.functional.conv2d(x, taps.view(1, 1, -1, 1), padding=(r, 0))
    return x.squeeze(1)


# A blur this wide (σ, px) or wider is computed on the image average-pooled by COARSE_BLUR_FACTOR and
# upsampled bilinearly: a 12 px Gaussian at full resolution is two 73-tap passes, +17 % of cart-0.4's
# step time in onnxruntime; pooled 4x it is two 19-tap passes on a 16th of the pixels. The result is
# a low-pass of the same width (its response differs from the Gaussian's by the pooling's box and
# the upsampling's tent), which is all the high-pass needs.
COARSE_BLUR_MIN_SIGMA_PX = 8.0
COARSE_BLUR_FACTOR = 4


def coarse_blur_factor(sigma_px: float, width_px: int) -> int:
    """The pooling factor `lowpass_images` uses for a blur of ``sigma_px`` on a ``width_px`` image."""
    f = COARSE_BLUR_FACTOR
    return f if sigma_px >= COARSE_BLUR_MIN_SIGMA_PX and width_px % f == 0 else 1


def lowpass_images(images: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """images float[B, W, W] low-passed to about ``sigma_px``: the Gaussian blur, or for a wide one
    (`coarse_blur_factor`) the Gaussian of ``sigma_px / f`` on the f-pooled image, upsampled back."""
    f = coarse_blur_factor(sigma_px, images.shape[-1])
    if f == 1:
        return blur_images(images, gaussian_kernel_1d(sigma_px).to(images.dtype))
    small = nn.functional.avg_pool2d(images.unsqueeze(1), f).squeeze(1)
    small = blur_images(small, gaussian_kernel_1d(sigma_px / f).to(images.dtype))
    return nn.functional.interpolate(small.unsqueeze(1), scale_factor=float(f), mode="bilinear",
                                     align_corners=False).squeeze(1)


# Second differences of a 3x3 neighbourhood, one output channel each: d²/dr² ([1, −2, 1] down the
# rows), d²/dr dc (the mixed central difference) and d²/dc² ([1, −2, 1] along the columns).
SECOND_DIFFERENCES = (
    ((0.0, 1.0, 0.0), (0.0, -2.0, 0.0), (0.0, 1.0, 0.0)),
    ((0.25, 0.0, -0.25), (0.0, 0.0, 0.0), (-0.25, 0.0, 0.25)),
    ((0.0, 0.0, 0.0), (1.0, -2.0, 1.0), (0.0, 0.0, 0.0)),
)
RADIAL_DIFFUSION_MAX_STEP = 0.25  # the explicit scheme's largest stable time step (px²)


def radial_blur_images(images: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """images float[B, W, W] blurred by a Gaussian of ``sigma_px`` along the radial direction only
    (from the image centre, the sensor, at (W − 1)/2), as anisotropic diffusion.

    The diffusion ∂x/∂t = uᵀ (∇²x) u along the unit radial direction u = (dr, dc)/|(dr, dc)| runs for
    T = σ²/2 in ⌈T/0.25⌉ explicit steps: each adds τ·(a·x_rr + 2b·x_rc + c·x_cc), a, b, c = dr², dr·dc,
    dc² over |(dr, dc)|² (clamped ≥ 1, so the centre is harmless), with the second differences of
    `SECOND_DIFFERENCES` in one convolution on the zero-padded image. It spreads a point by σ² of
    variance along u and none across it, and leaves whatever varies with the azimuth alone (spokes,
    tangential detail) as it is. The mixed difference's stencil is not monotone: a single bright pixel
    on a diagonal gets side lobes down to −9 % of its blurred peak (−1 to −2 % on an axis).

    The a, b, c maps are made from ``torch.arange`` in the forward pass, as
    `correlation.PolarRotator._tables` are: the exported file holds the 27 kernel numbers and one
    W×W table (|p|², which the exporter's constant folding computes from two W-vectors; 256 kB at
    W = 256), onnxruntime makes a, b, c from it at session start. ``sigma_px`` 0: the images."""
    if sigma_px <= 0:
        return images
    w = images.shape[-1]
    i = torch.arange(w, dtype=images.dtype) - (w - 1) / 2
    dr, dc = i[:, None], i[None, :]  # broadcast, not expanded: the exporter folds small-input ops
    n2 = (dr * dr + dc * dc).clamp_min(1.0)  # into constants, and an expanded table is one more
    a, b2, c = dr * dr / n2, 2 * dr * (dc / n2), dc * dc / n2  # (dc / n2 first: no dr·dc table)
    kernel = torch.tensor(SECOND_DIFFERENCES, dtype=images.dtype).unsqueeze(1)  # [3, 1, 3, 3]
    total = sigma_px ** 2 / 2
    steps = max(1, math.ceil(total / RADIAL_DIFFUSION_MAX_STEP - 1e-9))
    tau = total / steps
    x = images.unsqueeze(1)
    for _ in range(steps):
        d = nn.functional.conv2d(nn.functional.pad(x, (1, 1, 1, 1)), kernel)
        x = x + tau * (a * d[:, 0:1] + b2 * d[:, 1:2] + c * d[:, 2:3])
    return x.squeeze(1)


def support_disc(width_px: int, translation_cells: int) -> torch.Tensor:
    """float[W, W]: 1 inside the disc of radius ``(W−1)/2 − n − 1`` px about the image centre.

    Features are cut to this disc so that the DFT's circular correlation equals the linear one
    for every searched shift: a disc stays a disc under rotation (bilinear sampling spreads it
    by < 1 px), and shifted by at most n px per axis it stays inside the image, so nothing
    wraps round. Without it, returns beyond the image edge (radar sees ~160 m, the 0.4 m/px
    image ±51 m) would wrap to the opposite side and score as matches. It also drops the
    corners, which rotation would leave half-empty anyway.
    """
    centre = (width_px - 1) / 2
    radius = centre - translation_cells - 1
    rows = torch.arange(width_px, dtype=torch.float64) - centre
    r2 = rows[:, None] ** 2 + rows[None, :] ** 2
    return (r2 <= radius**2).to(torch.float32)


def mirror_averaged(masks_of, z: torch.Tensor) -> torch.Tensor:
    """(f(z) + flip(f(flip(z)))) / 2 for ``masks_of`` = f mapping images [B, ..., W] to masks [B, ..., W]
    (flip: the last axis, the columns, y → −y): masks that commute with the left/right mirror whatever
    f's handedness. z and its mirror image go through f as one batch of 2B (one call per layer, also in
    the exported graph). `MaskedCorrelator` with ``profile.mask_mirror_average``; distillation's target."""
    b = z.shape[0]
    m = masks_of(torch.cat([z, z.flip(-1)], dim=0))
    return 0.5 * (m[:b] + m[b:].flip(-1))


class MaskedCorrelator(nn.Module):
    """The paper's model for one `GridProfile`; see the module docstring for the options.

    Shapes: a *sweep* is float[B, W, W] (Cartesian kind) or float[B, A, B'] (polar kind, see
    `PolarToCartesian.input_shape`); volumes are float[B, K, N, N]; poses float[B, 3];
    covariances float[B, 3, 3]. The stream *state* is the previous sweep's half spectrum
    float[B, 2, W, W//2 + 1] in single mode, and the previous sweep itself in dual mode (its
    mask depends on the next sweep, so nothing can be precomputed).
    """

    def __init__(self, profile: GridProfile, masking: str = "learned", dft: str = "fft",
                 sweep_geometry: dict | None = None):
        super().__init__()
        if masking not in MASKINGS:
            raise ValueError(f"masking={masking!r}; choose one of {MASKINGS}")
        self.profile = profile
        self.masking = masking
        self.dft = dft
        self.dual = profile.mode == "dual"
        channels = 2 if self.dual else 1
        self.masker = (UNet(channels, channels, profile.unet_base_channels, profile.unet_depth)
                       if masking == "learned" else None)
        self.sweep_geometry = dict(sweep_geometry or CTS350X_GEOMETRY)
        self.to_cartesian = (PolarToCartesian(profile, self.sweep_geometry)
                             if profile.input_kind == "polar" else None)
        self.normaliser = make_normaliser(profile, self.to_cartesian)
        if masking == "cfar" and self.normaliser is None:
            # its thresholds are in normalised units; on raw power they would depend on the gain
            raise ValueError(f"masking='cfar' needs a profile with input_norm='floor-scale' "
                             f"(profile {profile.name!r} has {profile.input_norm!r})")
        self.cfar = make_cfar(profile, self.to_cartesian) if masking == "cfar" else None
        self.rotator = Rotator(profile)
        self.correlation = make_correlation(dft, profile.width_px, profile.translation_cells)
        self.register_buffer("candidates", candidate_poses(profile), persistent=False)
        self.register_buffer("support", support_disc(profile.width_px, profile.translation_cells),
                             persistent=False)
        self.register_buffer("cov_floor", torch.diag(torch.tensor(profile.covariance_floor)), persistent=False)

    # ------------------------------------------------------------------ masks and features
    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        """Sweeps of any leading shape as the masker and the features see them: the profile's
        input normalisation (`normalise`), or the sweeps themselves for ``input_norm="none"``."""
        return x if self.normaliser is None else self.normaliser(x)

    def mask(self, x: torch.Tensor) -> torch.Tensor:
        """Masks in [0, 1] of sweeps x: [B, H, W] (single) or [B, 2, H, W] (dual, prev+cur),
        in the input's own domain (polar masks for the polar kind); the same shape out.
        ``x`` is the raw sweep (normalised here when the profile asks for it)."""
        return self._mask(self.normalise(x))

    def _mask(self, z: torch.Tensor) -> torch.Tensor:
        """`mask` of already normalised sweeps z."""
        if self.masking == "external":
            raise ValueError("masking='external': the model has no masker; pass the masks")
        if self.cfar is not None:
            return self.cfar(z)
        if self.masker is None:
            return torch.ones_like(z)
        z = z if self.dual else z.unsqueeze(1)
        f = self.profile.mask_downsample if self.to_cartesian is None else 1
        if f > 1:  # mask on a coarser grid (see GridProfile.mask_downsample)
            m = self._unet_mask(nn.functional.avg_pool2d(z, f))
            m = nn.functional.interpolate(m, scale_factor=float(f), mode="bilinear",
                                          align_corners=False)
        else:
            m = self._unet_mask(z)
        return m if self.dual else m.squeeze(1)

    def _unet_mask(self, z: torch.Tensor) -> torch.Tensor:
        """The U-Net's masks of z [B, C, H, W]; with ``profile.mask_mirror_average`` the mean of the
        mask and the mirrored mask of the mirror image, (M(z) + flip(M(flip(z)))) / 2 (flip: the
        columns, y → −y), so the masks commute with the mirror whatever the kernels' handedness.
        The 2x pooling and bilinear upsampling around it commute with the flip on even sizes."""
        if not self.profile.mask_mirror_average:
            return self.masker(z)
        return mirror_averaged(self.masker, z)

    def _to_features(self, z: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """``S = M ⊙ Z`` as a Cartesian image float[B, W, W] (polar: masked, then mapped), from
        a normalised sweep z."""
        masked = mask * z
        cart = masked if self.to_cartesian is None else self.to_cartesian(masked)
        # the profile's band limits (GridProfile.feature_radial_blur_px / feature_blur_px /
        # feature_highpass_px): content fixed to the pixel grid or to the sensor out, before it can
        # match itself at zero motion; the radial blur first, smoothing along range only and keeping
        # the tangential detail that yaw is read from
        if self.profile.feature_radial_blur_px > 0:
            cart = radial_blur_images(cart * self.support, self.profile.feature_radial_blur_px)
        if self.profile.feature_blur_px > 0:
            cart = lowpass_images(cart * self.support, self.profile.feature_blur_px)
        if self.profile.feature_highpass_px > 0:
            cart = cart - lowpass_images(cart * self.support, self.profile.feature_highpass_px)
        return cart * self.support

    def _masks(self, prev, cur, prev_mask, cur_mask):
        """Masks of the normalised sweeps prev, cur (or the caller's, for external masking)."""
        if self.masking == "external":
            if prev_mask is None or cur_mask is None:
                raise ValueError("masking='external' needs prev_mask and cur_mask (same shapes "
                                 "as the sweeps, values in [0, 1])")
            return prev_mask, cur_mask
        if prev_mask is not None or cur_mask is not None:
            raise ValueError(f"masking={self.masking!r} predicts its own masks; "
                             "build the model with masking='external' to pass masks")
        if self.dual:
            both = self._mask(torch.stack([prev, cur], dim=1))
            return both[:, 0], both[:, 1]
        return self._mask(prev), self._mask(cur)

    def features(self, prev, cur, prev_mask=None, cur_mask=None):
        """(S_prev, S_cur), Cartesian float[B, W, W] each: the images the search matches."""
        prev, cur = self.normalise(prev), self.normalise(cur)
        m_prev, m_cur = self._masks(prev, cur, prev_mask, cur_mask)
        return self._to_features(prev, m_prev), self._to_features(cur, m_cur)

    def sweep_features(self, sweep, mask=None) -> torch.Tensor:
        """``S = M ⊙ Z`` of one sweep per batch item (single mode), Cartesian float[B, W, W]."""
        z = self.normalise(sweep)
        if self.masking == "external":
            if mask is None:
                raise ValueError("masking='external' needs the sweep's mask")
            return self._to_features(z, mask)
        return self._to_features(z, self._mask(z))

    # ------------------------------------------------------------------ pair form
    def correlation_volume(self, prev, cur, prev_mask=None, cur_mask=None) -> torch.Tensor:
        """float[B, K, N, N] scores of the pose candidates (`candidates`, same layout)."""
        s_prev, s_cur = self.features(prev, cur, prev_mask, cur_mask)
        corr = self.correlation
        return corr.correlate(corr.spectrum(s_prev), corr.spectrum(self.rotator(s_cur)))

    def pose_from_volume(self, volume: torch.Tensor):
        """(pose [B, 3], covariance [B, 3, 3]) by soft-argmax with the profile's two βs; the
        covariance is `covariance_from_moment` of the beta_cov moment."""
        p = self.profile
        pose = read_pose(volume, self.candidates, p)
        cov = weighted_covariance(candidate_weights(volume, p.beta_cov), self.candidates.reshape(-1, 3))
        return pose, self.covariance_from_moment(cov)

    def covariance_from_moment(self, moment: torch.Tensor) -> torch.Tensor:
        """float[B, 3, 3] ``cov_scale · moment + floor``: the covariance the model reports, from
        the second moment of softmax(beta_cov · C) (`GridProfile.cov_scale`, `covariance_floor`)."""
        scale = self.profile.cov_scale
        return (moment if scale == 1.0 else scale * moment) + self.cov_floor

    def forward(self, prev, cur, prev_mask=None, cur_mask=None):
        """(pose float[B, 3], covariance float[B, 3, 3]) of ``cur``'s frame in ``prev``'s."""
        return self.pose_from_volume(self.correlation_volume(prev, cur, prev_mask, cur_mask))

    # ------------------------------------------------------------------ stream form
    def initial_state(self, cur, cur_mask=None) -> torch.Tensor:
        """The state a stream keeps after its first sweep ``cur``."""
        if self.dual:
            return cur
        return self.correlation.spectrum(self.sweep_features(cur, cur_mask))

    def stream_step(self, cur, prev_state, cur_mask=None):
        """(pose, covariance, new_state) for sweep ``cur`` against the previous step's state.

        Single mode masks and transforms each sweep once: the new state is the spectrum of the
        yaw-0 slice of the rotated stack (the unrotated image), not a fresh transform; with a
        resampled identity (`Rotator`) that slice is blurred and the state is transformed anew.
        """
        if self.dual:
            if cur_mask is not None:
                raise ValueError("dual mode predicts both masks itself; cur_mask is not used")
            pose, cov = self(prev_state, cur)
            return pose, cov, cur
        corr = self.correlation
        features = self.sweep_features(cur, cur_mask)
        spectra = corr.spectrum(self.rotator(features))
        pose, cov = self.pose_from_volume(corr.correlate(prev_state, spectra))
        return pose, cov, self.state_of(features, spectra)

    def state_of(self, features: torch.Tensor, spectra: torch.Tensor) -> torch.Tensor:
        """The stream state (the unrotated features' spectrum) of features [B, W, W] whose
        rotated stack has the spectra [B, K, 2, W, G]: the yaw-0 slice where it is the image
        itself, a fresh transform where the rotation resamples it (`Rotator`)."""
        if self.rotator.exact_identity:
            return spectra[:, self.rotator.zero_index]
        return self.correlation.spectrum(features)
