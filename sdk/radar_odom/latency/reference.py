"""The numpy (pocketfft) + OpenCV reference of the correlative search, for speed ratios."""
from __future__ import annotations

import math

import numpy as np


def softmax_weights(scores: np.ndarray, beta: float) -> np.ndarray:
    """float64[N]: softmax(β·scores), the candidate weights of the graph's soft-argmax (paper eq. 3)."""
    z = beta * scores
    e = np.exp(z - z.max())
    return e / e.sum()


def _rotation_matrix(yaw_rad: float, width_px: int) -> np.ndarray:
    """2×3 ``warpAffine`` map (with WARP_INVERSE_MAP) from output to input pixel (u=col, v=row)
    that samples ``S(R(yaw)ᵀ p)`` about the image centre: the graph's rotation convention
    (x = cW − row forward, y = col − cW right)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    cw = (width_px - 1) / 2
    return np.array([[c, s, cw * (1 - c - s)], [-s, c, cw * (1 - c + s)]], dtype=np.float64)


class FFTReference:
    """The correlative search of a `GridProfile` in numpy (pocketfft) and OpenCV.

    ``search(prev_spectrum, cur_image)`` takes the previous masked image's half spectrum
    (complex [W, W//2+1], i.e. the stream state) and the current masked image [W, W] and returns
    ``(pose [3], covariance [3, 3])`` by the profile's soft-argmax. With ``search_settings``
    (the ``radar_odom.search`` metadata of a fast-search model) it runs the same coarse-to-fine
    search: a yaw picked on spectra cropped to ``W / coarse_factor`` px, then the band of
    ``2b + 1`` yaws and yaw 0 at full resolution; with the metadata of a decoupled-search model
    (``kind: decoupled``) use `DecoupledReference` (`make_reference` picks); otherwise every candidate.
    """

    def __init__(self, profile, search_settings: dict | None = None):
        self.profile = profile
        self.width = profile.width_px
        self.n = profile.translation_cells
        self.yaws = np.asarray(profile.rotations_rad, dtype=np.float64)
        offsets = np.arange(-self.n, self.n + 1) * profile.resolution_m
        self.trans = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1)  # [N, N, 2]
        self.settings = search_settings if search_settings and search_settings.get(
            "band_rotations", len(self.yaws)) < len(self.yaws) else None

    def _rotated(self, image: np.ndarray, yaws) -> np.ndarray:
        import cv2

        w = image.shape[-1]
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        return np.stack([cv2.warpAffine(image, _rotation_matrix(y, w), (w, w), flags=flags,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
                         for y in yaws])

    @staticmethod
    def _volume(prev_spectrum, rotated, n):
        """[K, N, N] correlation window, the graph's layout (see correlation.py)."""
        w = rotated.shape[-1]
        full = np.fft.irfft2(np.conj(prev_spectrum)[None] * np.fft.rfft2(rotated), s=(w, w))
        return np.roll(full, (n, n), axis=(-2, -1))[:, : 2 * n + 1, : 2 * n + 1][:, :, ::-1]

    def _crop(self, spectrum, low):
        half = low // 2
        rows = np.r_[0:half, self.width - half:self.width]
        out = spectrum[rows, : half + 1].copy()
        out[half, :] = 0
        out[:, half] = 0
        return out

    def band(self, prev_spectrum, cur_spectrum) -> np.ndarray:
        """Indices of the yaws evaluated at full resolution."""
        k = len(self.yaws)
        if self.settings is None:
            return np.arange(k)
        f, stride = int(self.settings["coarse_factor"]), int(self.settings["coarse_stride"])
        size = int(self.settings["band_rotations"])
        low = self.width // f
        centre = k // 2
        idx = np.array(sorted({*range(centre, -1, -stride), *range(centre, k, stride)}))
        cur_low = np.fft.irfft2(self._crop(cur_spectrum, low), s=(low, low)).astype(np.float32)
        rotated = self._rotated(cur_low, self.yaws[idx])
        vol = self._volume(self._crop(prev_spectrum, low), rotated, max(1, math.ceil(self.n / f)))
        norm = np.sqrt((rotated.astype(np.float64) ** 2).reshape(len(idx), -1).sum(axis=1) + 1e-12)
        best = int(idx[np.argmax(vol.reshape(len(idx), -1).max(axis=1) / norm)])
        start = min(max(best - size // 2, 0), k - size)
        return np.arange(start, start + size)

    def search(self, prev_spectrum: np.ndarray, cur_image: np.ndarray):
        cur_image = np.ascontiguousarray(cur_image, dtype=np.float32)
        cur_spectrum = np.fft.rfft2(cur_image) if self.settings is not None else None
        idx = self.band(prev_spectrum, cur_spectrum)
        # the fast graph also scores yaw 0 (the unrotated image) whatever the band
        idx = np.union1d(idx, [len(self.yaws) // 2])
        rotated = self._rotated(cur_image, self.yaws[idx])
        if getattr(self.profile, "rotation_identity", "exact") == "exact":
            rotated[np.flatnonzero(idx == len(self.yaws) // 2)] = cur_image  # yaw 0: the image itself
        # else the graph resamples yaw 0 like every other yaw: warpAffine it too (the same work;
        # OpenCV's bilinear at 0° is the image itself, so the poses stay the exact identity's)
        vol = self._volume(prev_spectrum, rotated, self.n)
        cand = np.concatenate([np.broadcast_to(self.trans, (len(idx), *self.trans.shape)),
                               np.broadcast_to(self.yaws[idx][:, None, None, None],
                                               (len(idx), *self.trans.shape[:2], 1))], axis=-1)
        cand = cand.reshape(-1, 3)
        flat = vol.reshape(-1).astype(np.float64)

        w = softmax_weights(flat, self.profile.beta_pose)
        pose = w @ cand
        wc = softmax_weights(flat, self.profile.beta_cov)
        centred = cand - wc @ cand
        cov = self.profile.covariance_from_moment((centred * wc[:, None]).T @ centred)  # as the graph
        return pose, cov


def _bilinear(image: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` [H, W] at float positions (zeros outside), float64: the
    graph's sampler (`radar_odom_export.correlation.gather_lerp` on a zero border)."""
    h, w = image.shape
    padded = np.zeros((h + 3, w + 3), dtype=np.float64)
    padded[1:h + 1, 1:w + 1] = image
    rows = np.clip(rows, -1.0, float(h)) + 1.0
    cols = np.clip(cols, -1.0, float(w)) + 1.0
    r0, c0 = np.floor(rows).astype(np.int64), np.floor(cols).astype(np.int64)
    fr, fc = rows - r0, cols - c0
    top = padded[r0, c0] + fc * (padded[r0, c0 + 1] - padded[r0, c0])
    bottom = padded[r0 + 1, c0] + fc * (padded[r0 + 1, c0 + 1] - padded[r0 + 1, c0])
    return top + fr * (bottom - top)


class DecoupledReference(FFTReference):
    """The decoupled search (Fast-MbyM; `radar_odom_export.decoupled_search`) in numpy: the yaw
    from a circular correlation of the two magnitude spectra (``|F|``) resampled to 180° × R
    rings, along the angle axis (``numpy.fft.rfft``), read at its parabolic peak; the current
    image rotated once by it; one FFT translation correlation; x, y by the soft-argmax. The
    settings are the ``radar_odom.search`` metadata (``angle_oversample``, ``radii``,
    ``radius_min``, ``radius_max``, ``beta_yaw``).
    """

    def __init__(self, profile, search_settings: dict | None = None):
        super().__init__(profile, None)
        st = dict(search_settings or {})
        w = self.width
        self.bin_rad = profile.rotation_step_rad / int(st.get("angle_oversample", 1))
        a = int(round(math.pi / self.bin_rad))
        half = w / 2
        radii = np.linspace(float(st.get("radius_min", 0.1)) * half, float(st.get("radius_max", 0.6)) * half,
                            int(st.get("radii", 64)))
        angles = np.arange(a) * self.bin_rad
        s = (profile.num_rotations // 2) * int(st.get("angle_oversample", 1))
        self.shifts = np.arange(-s, s + 1)
        self.ring_rows = radii[:, None] * np.cos(angles)[None, :] + w // 2  # [R, A], row kr + W/2
        self.ring_cols = radii[:, None] * np.sin(angles)[None, :]
        self.beta_yaw = float(st.get("beta_yaw", 200.0))
        c_w = (w - 1) / 2
        n = self.n
        idx = np.arange(n, w - n, dtype=np.float64)
        self.x_px, self.y_px = (c_w - idx)[:, None], (idx - c_w)[None, :]

    def rings(self, spectrum: np.ndarray) -> np.ndarray:
        """Half spectrum (complex [W, W//2 + 1]) → zero-mean ring profiles [R, A] of ``|F|``."""
        w = self.width
        mag = np.sqrt(spectrum.real ** 2 + spectrum.imag ** 2 + 1e-12)
        centred = np.concatenate([mag[w // 2:], mag[: w // 2]], axis=0)
        rings = _bilinear(centred, self.ring_rows, self.ring_cols)
        return rings - rings.mean(axis=1, keepdims=True)

    def yaw(self, prev_spectrum: np.ndarray, cur_spectrum: np.ndarray):
        """(yaw rad, yaw variance, cosine similarity per shift [2S + 1])."""
        p, c = self.rings(prev_spectrum), self.rings(cur_spectrum)
        a = p.shape[1]
        full = np.fft.irfft((np.conj(np.fft.rfft(p, axis=1)) * np.fft.rfft(c, axis=1)).sum(axis=0), n=a)
        cosine = full[self.shifts % a] / np.sqrt((p ** 2).sum() * (c ** 2).sum() + 1e-30)
        yaws = self.shifts * self.bin_rad
        yaw = _parabolic_peak(cosine, yaws, self.bin_rad)
        z = self.beta_yaw * cosine
        wt = np.exp(z - z.max())
        wt /= wt.sum()
        return yaw, float(wt @ (yaws - yaw) ** 2), cosine

    def rotate(self, image: np.ndarray, yaw: float) -> np.ndarray:
        """``S(R(yaw)ᵀ p)`` on the central (W − 2n)² square, zero-padded back to [W, W]."""
        c_w, n = (self.width - 1) / 2, self.n
        cos, sin = math.cos(yaw), math.sin(yaw)
        src_x = cos * self.x_px + sin * self.y_px
        src_y = -sin * self.x_px + cos * self.y_px
        out = np.zeros((self.width, self.width))
        out[n:self.width - n, n:self.width - n] = _bilinear(image, c_w - src_x, c_w + src_y)
        return out

    def search(self, prev_spectrum: np.ndarray, cur_image: np.ndarray):
        cur_image = np.ascontiguousarray(cur_image, dtype=np.float32)
        yaw, yaw_var, _ = self.yaw(prev_spectrum, np.fft.rfft2(cur_image))
        vol = self._volume(prev_spectrum, self.rotate(cur_image, yaw)[None], self.n)
        cand = self.trans.reshape(-1, 2)
        flat = vol.reshape(-1).astype(np.float64)

        w = softmax_weights(flat, self.profile.beta_pose)
        pose = np.array([*(w @ cand), yaw])
        wc = softmax_weights(flat, self.profile.beta_cov)
        centred = cand - wc @ cand
        moment = np.zeros((3, 3))
        moment[:2, :2] = (centred * wc[:, None]).T @ centred
        moment[2, 2] = yaw_var
        return pose, self.profile.covariance_from_moment(moment)


def _parabolic_peak(scores: np.ndarray, values: np.ndarray, step: float) -> float:
    """The value at the best score, moved by a parabola through it and its neighbours (clipped
    to ±½ step; none on the border or where the parabola does not curve down)."""
    k = int(np.argmax(scores))
    delta = 0.0
    if 0 < k < len(scores) - 1:
        cm, c0, cp = scores[k - 1], scores[k], scores[k + 1]
        curve = cm - 2 * c0 + cp
        if curve < 0:
            delta = float(np.clip((cm - cp) / (2 * curve), -0.5, 0.5))
    return float(values[k] + delta * step)


def make_reference(profile, search_settings: dict | None = None) -> FFTReference:
    """The numpy reference of the search a model's ``radar_odom.search`` metadata names."""
    if (search_settings or {}).get("kind") == "decoupled":
        return DecoupledReference(profile, search_settings)
    return FFTReference(profile, search_settings)


def state_to_image(state: np.ndarray, width_px: int) -> np.ndarray:
    """The masked image [W, W] whose half spectrum is the stream state [1, 2, W, W//2+1]."""
    spec = state[0, 0].astype(np.float64) + 1j * state[0, 1].astype(np.float64)
    return np.fft.irfft2(spec, s=(width_px, width_px)).astype(np.float32)


def state_to_spectrum(state: np.ndarray) -> np.ndarray:
    return state[0, 0].astype(np.float64) + 1j * state[0, 1].astype(np.float64)

