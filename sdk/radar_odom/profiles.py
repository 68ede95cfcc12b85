"""Grid profiles: the one definition of a model's grid, shared by training, export and runtime.

A profile fixes the Cartesian image (``resolution_m`` per pixel, ``width_px`` square, image up =
+x forward, right = +y), the pose candidates searched (translations within
``±max_translation_m`` on the pixel grid, rotations ``rotation_step_rad`` apart within
``±rotation_range_rad``), the soft-argmax temperatures (``beta_pose`` for the pose and
``beta_cov`` for the covariance, paper eq. 3 and Sec. 4.4) and the masker's input kind.
The exported ONNX file stores the profile in ``metadata_props`` (`to_metadata`) and the runtime
reads it back (`from_metadata`): it is never re-typed.

Default translation window: ±8 m. Sweeps are 0.25 s apart (4 Hz), so ±8 m covers 32 m/s
(115 km/h) forward motion; the paper's ±50 m window is the ``paper_window=True`` variant.
Rotations: the paper's ±15° in 0.5° steps (61 candidates) covers 60°/s yaw rates at 4 Hz.

Input normalisation (``input_norm``): ``"none"`` feeds the sweep's power to the model as it is
(the models shipped before this field existed; their metadata lacks the key and reads back as
``"none"``); ``"floor-scale"`` removes a range-dependent noise floor and divides by a robust
per-sweep scale inside the graph (``radar_odom_export.normalise``), so that a radar's gain and
offset do not change the correlation's scale and with it the soft-argmax temperature. The
``cfar_*`` fields parameterise the training-free ``masking="cfar"`` model (cell-averaging CFAR
on the normalised image, ``radar_odom_export.cfar``); other maskings ignore them.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace

SWEEP_PERIOD_S = 0.25
PAPER_TRANSLATION_M = 50.0
INPUT_NORMS = ("none", "floor-scale")
ROTATION_IDENTITIES = ("exact", "resampled")
ROTATION_KERNELS = ("bilinear", "cubic")


# fields a profile writes only when they differ from this value (what files without them mean)
OPTIONAL_FIELDS = {"feature_highpass_px": 0.0, "feature_blur_px": 0.0, "feature_radial_blur_px": 0.0,
                   "mask_mirror_average": False}


@dataclass(frozen=True)
class GridProfile:
    name: str
    resolution_m: float
    width_px: int
    max_translation_m: float = 8.0
    rotation_range_rad: float = math.pi / 12
    rotation_step_rad: float = math.pi / 360
    beta_pose: float = 1.0
    beta_cov: float = 1.0
    input_kind: str = "cartesian"  # "cartesian" | "polar"
    mode: str = "single"  # "single" | "dual"
    near_range_m: float = 2.5  # power closer than this is blanked (the vehicle itself)
    unet_base_channels: int = 8
    unet_depth: int = 5
    # The masker runs on the image average-pooled by this factor and its mask is upsampled
    # bilinearly: the mask is smooth at the scale of objects (cars, walls), so 0.2 and 0.4 m/px
    # models mask at 0.8 m/px and the U-Net costs the same at every resolution.
    mask_downsample: int = 1
    # The mask averaged over the left/right mirror (image columns, y → −y): (M(x) + flip(M(flip(x)))) / 2,
    # x and its mirror image through the U-Net as one batch of two. The search after the masker is
    # mirror-equivariant already, so with it the whole graph is, with the masker's weights as trained: no
    # yaw from the U-Net's handedness (the straight-road bias, docs/yaw-precision.md), at twice the
    # masker's cost. Cartesian input only (a polar sweep's mirror is its azimuths reversed). False in
    # every file made before this field.
    mask_mirror_average: bool = False
    # The soft-argmax covariance is a moment of a distribution over grid cells: when β·C puts
    # its weight on one cell it tends to 0, although the true pose is anywhere within that cell.
    # This many cells' uniform quantisation variance, (c·cell)²/12 per axis, is added to it
    # (`covariance_floor`); 0 gives the paper's eq. 3 alone. `radar-odom calibrate` fits it (and
    # the yaw's, and cov_scale) to the errors of the pose read-out, which is sub-cell precise.
    cov_floor_cells: float = 1.0
    cov_floor_yaw_cells: float = 1.0  # the same for yaw, in yaw steps
    # The covariance is cov_scale × the beta_cov moment + the floor: one temperature shapes the
    # moment, the scale and the two floors let the calibration (per-axis maximum likelihood) make
    # a sharp peak's covariance small and a ridge's large at once.
    cov_scale: float = 1.0
    # The pose is the soft-argmax over the candidates within this many cells (and yaw steps) of
    # the best one; the covariance still uses them all. 0: over every candidate (paper eq. 3),
    # which pulls the pose towards the window centre (zero motion) whenever the volume is not
    # sharply peaked, and averages the modes of an ambiguous one.
    pose_window_cells: int = 0
    # How the pose is read off the volume: "soft-argmax" (paper eq. 3 with beta_pose, within the
    # pose window) or "parabolic": the best candidate refined by a parabola through its
    # neighbours on each axis, which keeps sub-cell precision however tall the correlation peak
    # is (a scene with much structure makes β·C so peaked that the soft-argmax snaps to a cell).
    # The covariance is the beta_cov soft-argmax moment either way.
    pose_estimator: str = "soft-argmax"
    # How yaw 0 is scored: "exact" (the files made before this field: the image itself, while
    # every other yaw is an interpolated, slightly blurred copy, so yaw 0 scores higher than it
    # should and a gentle curve of up to ~1 yaw step per sweep reads as straight) or
    # "resampled": yaw 0 goes through the same resampling as every other yaw (the polar round
    # trip of `PolarRotator`, in training and in both exported searches), so no yaw is favoured.
    rotation_identity: str = "exact"
    # The kernel of the polar rotation's first resampling (Cartesian image → polar grid), where
    # each yaw candidate's samples land at another sub-pixel phase of the image: "bilinear" (the
    # files made before this field) blurs by an amount that depends on that phase, least where the
    # samples sit on the pixels themselves — at the search centre, yaw 0 — so every candidate but
    # the centre loses high-frequency energy and small turns read shrunk toward 0 (simulated
    # 0.61 °/sweep curve: 0.41 of the turn with bilinear, 0.68 with cubic, 0.65 with an exact
    # Fourier rotation; benchmarks/yaw_precision.py). "cubic": Keys' cubic convolution (a = −0.5).
    rotation_kernel: str = "bilinear"
    # Band limits of the masked features before they are correlated (Gaussian sigmas, pixels; 0: off,
    # as in every file made before these fields). A sweep drawn on a pixel grid carries content that
    # is fixed to the sensor rather than to the world, and such content matches itself best at zero
    # motion, pulling every match toward standing still (docs/yaw-precision.md, "Band limits"):
    # - feature_highpass_px: the features minus their low-pass of this sigma (8 px and wider: computed on
    #   the image pooled 4x, +2-10 % step time instead of +17 %). Removes the broad
    #   sensor-centred content (the near-range clutter disc, the range trend the ring normalisation
    #   leaves): cart-0.4 at 12 px, shared RADIATE drive 3.63 → 3.38 %, simulated drives 10.25 → 8.53 %.
    # - feature_blur_px: a blur of this sigma. Removes the fine texture of the grid (range bins ~10x
    #   finer than a pixel sampled by a bilinear remap, the masker's pooling phase), which pulls small
    #   turns to 0: a 0.5 deg/sweep simulated bend is read as 0.64 of the turn, 0.88 at 2 px, and the
    #   real drive's rotation drift falls 35 % at 1 px — but straight simulated roads gain a yaw bias and
    #   the real drive's translation error rises unless the radar's mount yaw is corrected (`radar-odom
    #   adapt`): measured, not on in the shipped models.
    # - feature_radial_blur_px: a Gaussian of this sigma along the radial direction only (away from the
    #   sensor, the image centre; anisotropic diffusion, `radial_blur_images`), applied first. Smooths
    #   the range-sharp texture of the grid but keeps the tangential detail that yaw is read from: a
    #   0.5 deg/sweep simulated bend reads 0.76/0.82 of the turn (urban/open) at 1 px + hp12, 0.63/0.77
    #   with hp12 alone (benchmarks/band_limits.py --parts curves). Measured, not on in the shipped models.
    feature_highpass_px: float = 0.0
    feature_blur_px: float = 0.0
    feature_radial_blur_px: float = 0.0
    # Input normalisation (module docstring): "none" | "floor-scale". The floor is this quantile
    # over azimuth of each range ring, the scale this quantile of the floor-free image over the
    # support disc; the normalised image is clipped at norm_clip (0: no clip).
    input_norm: str = "none"
    norm_floor_quantile: float = 0.5
    norm_scale_quantile: float = 0.99
    norm_clip: float = 4.0
    # masking="cfar": a pixel is kept where the normalised image exceeds cfar_alpha × its mean
    # over a cfar_window_m box and exceeds cfar_min_level (normalised units: 1 = the scale).
    # Chosen on a real Oxford Navtech pair at 0.4 and 0.8 m/px among windows 2–8 m, α 1–5 and
    # levels 0.05–0.5: they keep ~2 % of the pixels, and widen the gap between the true pose's
    # score and the best one elsewhere from 12–19 % (raw normalised sweeps) to 57–61 %.
    cfar_window_m: float = 4.0
    cfar_alpha: float = 3.0
    cfar_min_level: float = 0.2

    def __post_init__(self):
        if self.resolution_m <= 0 or self.width_px < 16:
            raise ValueError(f"profile {self.name!r}: resolution_m must be > 0 and width_px >= 16")
        if self.input_kind not in ("cartesian", "polar"):
            raise ValueError(f"profile {self.name!r}: input_kind must be 'cartesian' or 'polar'")
        if self.mode not in ("single", "dual"):
            raise ValueError(f"profile {self.name!r}: mode must be 'single' or 'dual'")
        if self.translation_cells * 2 + 1 > self.width_px:
            raise ValueError(f"profile {self.name!r}: translation window wider than the image")
        if self.mask_downsample < 1 or self.width_px % (2**self.unet_depth * self.mask_downsample):
            raise ValueError(
                f"profile {self.name!r}: width_px must be divisible by 2**unet_depth × mask_downsample"
            )
        if self.mask_mirror_average and self.input_kind != "cartesian":
            raise ValueError(f"profile {self.name!r}: mask_mirror_average needs input_kind='cartesian'")
        if self.pose_estimator not in ("soft-argmax", "parabolic"):
            raise ValueError(f"profile {self.name!r}: pose_estimator must be 'soft-argmax' or 'parabolic'")
        if self.rotation_identity not in ROTATION_IDENTITIES:
            raise ValueError(f"profile {self.name!r}: rotation_identity must be one of {ROTATION_IDENTITIES}")
        if self.rotation_kernel not in ROTATION_KERNELS:
            raise ValueError(f"profile {self.name!r}: rotation_kernel must be one of {ROTATION_KERNELS}")
        if not 0.0 <= self.feature_blur_px <= self.translation_cells / 2:
            raise ValueError(f"profile {self.name!r}: feature_blur_px must lie in [0, {self.translation_cells / 2:g}] "
                             "(half the translation window)")
        if not 0.0 <= self.feature_radial_blur_px <= self.translation_cells / 2:
            raise ValueError(f"profile {self.name!r}: feature_radial_blur_px must lie in "
                             f"[0, {self.translation_cells / 2:g}] (half the translation window)")
        highpass = self.feature_highpass_px
        if not (highpass == 0.0 or self.feature_blur_px < highpass <= self.width_px / 4):
            raise ValueError(f"profile {self.name!r}: feature_highpass_px must be 0 or lie in (feature_blur_px, "
                             f"{self.width_px / 4:g}]")
        if self.input_norm not in INPUT_NORMS:
            raise ValueError(f"profile {self.name!r}: input_norm must be one of {INPUT_NORMS}")
        if not (0 < self.norm_floor_quantile <= 1 and 0 < self.norm_scale_quantile <= 1 and self.norm_clip >= 0):
            raise ValueError(f"profile {self.name!r}: norm quantiles must lie in (0, 1] and norm_clip >= 0")
        if self.cfar_window_m <= 0 or self.cfar_alpha <= 0 or self.cfar_min_level < 0:
            raise ValueError(f"profile {self.name!r}: cfar_window_m and cfar_alpha must be > 0, "
                             "cfar_min_level >= 0")

    # --- derived quantities (never stored twice) ---
    @property
    def translation_cells(self) -> int:
        """n such that translations -n..n pixels (inclusive) are searched on each axis."""
        return int(math.floor(self.max_translation_m / self.resolution_m + 1e-9))

    @property
    def num_translations(self) -> int:
        return 2 * self.translation_cells + 1

    @property
    def rotations_rad(self) -> list[float]:
        """Rotation candidates, symmetric about 0 and including 0."""
        k = int(round(self.rotation_range_rad / self.rotation_step_rad))
        return [i * self.rotation_step_rad for i in range(-k, k + 1)]

    @property
    def num_rotations(self) -> int:
        return len(self.rotations_rad)

    @property
    def covariance_floor(self) -> tuple[float, float, float]:
        """Variances (m², m², rad²) added to the covariance's diagonal: ``(c·cell)² / 12`` for
        the x and y cell (``resolution_m``, c = ``cov_floor_cells``) and the yaw step
        (c = ``cov_floor_yaw_cells``)."""
        r = (self.cov_floor_cells * self.resolution_m) ** 2 / 12.0
        return (r, r, (self.cov_floor_yaw_cells * self.rotation_step_rad) ** 2 / 12.0)

    def covariance_from_moment(self, moment):
        """float64[..., 3, 3] the covariance the model reports from the beta_cov second moment(s)
        ``moment`` [..., 3, 3] (m², m·rad, rad²): ``cov_scale · moment + diag(covariance_floor)``
        (numpy; the graph's torch twin is ``MaskedCorrelator.covariance_from_moment``)."""
        import numpy as np

        return self.cov_scale * np.asarray(moment, np.float64) + np.diag(self.covariance_floor)

    @property
    def extent_m(self) -> float:
        """Half width of the image in metres (pixel-centre to image-edge)."""
        return self.width_px * self.resolution_m / 2

    @property
    def support_radius_m(self) -> float:
        """Radius (m) of the disc about the sensor that a Cartesian model correlates.

        ``((W − 1)/2 − n − 1) · resolution_m`` for W = ``width_px`` and n = ``translation_cells``:
        the exporter cuts features to this disc (``support_disc`` in the export package) so that
        no searched shift wraps round the DFT. A sweep must reach at least this far to fill it.
        """
        return ((self.width_px - 1) / 2 - self.translation_cells - 1) * self.resolution_m

    def with_(self, **changes) -> GridProfile:
        return replace(self, **changes)

    # --- ONNX metadata round trip ---
    def to_metadata(self) -> dict[str, str]:
        return {"radar_odom.profile": json.dumps(self.to_dict(), sort_keys=True)}

    def to_dict(self) -> dict:
        """The fields as a dict, less those added since files were first written that hold the
        value a file without them reads as (`OPTIONAL_FIELDS`): a profile that does not use
        them writes the same text, hence the same digest, as before they existed."""
        d = asdict(self)
        for k, absent in OPTIONAL_FIELDS.items():
            if d.get(k) == absent:
                del d[k]
        return d

    @classmethod
    def from_metadata(cls, meta: dict[str, str]) -> GridProfile:
        if "radar_odom.profile" not in meta:
            raise KeyError("metadata has no 'radar_odom.profile' entry: not a radar-odom model")
        return cls.from_dict(json.loads(meta["radar_odom.profile"]))

    @classmethod
    def from_dict(cls, d: dict) -> GridProfile:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


PROFILES: dict[str, GridProfile] = {
    p.name: p
    for p in (
        GridProfile("cart-0.8", resolution_m=0.8, width_px=128, input_norm="floor-scale", rotation_kernel="cubic"),
        # cart-0.4 scores yaw 0 resampled like every other yaw (the shipped model is trained so);
        # trained so, cart-0.8 measured worse on held-out drives (README) and keeps the exact one
        # cart-0.4 also takes the broad sensor-centred content out of its features (feature_highpass_px);
        # cart-0.8 measured no different with it (4.96 vs 4.97 % on the shared drive) and goes without
        GridProfile("cart-0.4", resolution_m=0.4, width_px=256, mask_downsample=2, input_norm="floor-scale",
                    rotation_identity="resampled", rotation_kernel="cubic", feature_highpass_px=12.0),
        GridProfile("cart-0.2", resolution_m=0.2, width_px=512, mask_downsample=4, input_norm="floor-scale",
                    rotation_kernel="cubic"),
        GridProfile("polar-0.4", resolution_m=0.4, width_px=256, input_kind="polar", input_norm="floor-scale"),
        GridProfile("dual-0.8", resolution_m=0.8, width_px=128, mode="dual", input_norm="floor-scale"),
    )
}


def get_profile(name: str, paper_window: bool = False) -> GridProfile:
    """Named profile; ``paper_window=True`` selects the paper's ±50 m translation search."""
    try:
        p = PROFILES[name]
    except KeyError:
        raise KeyError(f"unknown profile {name!r}; choose one of {sorted(PROFILES)}") from None
    if paper_window:
        p = p.with_(max_translation_m=min(PAPER_TRANSLATION_M, p.extent_m - p.resolution_m))
    return p
