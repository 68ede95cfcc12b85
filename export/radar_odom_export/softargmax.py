"""Temperature-controlled soft-argmax over the correlation volume (paper Alg. 3, eq. 3).

Each candidate s gets the weight ``ω_s = softmax(β·C)_s`` over all K·N·N candidates; the pose
is ``p̄ = Σ ω_s p_s`` and the covariance ``Σ̄ = Σ ω_s p_s p_sᵀ − p̄ p̄ᵀ`` over (x m, y m, yaw rad).

The paper tunes a second temperature used only for the covariance (calibration, Sec. 4.4), so
the pose uses ``beta_pose`` and the covariance a separate softmax with ``beta_cov``: the
covariance is the second central moment of the ``beta_cov`` distribution (eq. 3 with that β).

Numerics: correlation values scale with image power (a raw 256² scan gives C in the
thousands), so ``β·C`` can be huge. ``torch.softmax`` subtracts the maximum before
exponentiating, which keeps the weights finite (a very peaked volume degrades gracefully to a
hard argmax, never NaN). The covariance is computed as ``Σ ω (p − p̄)(p − p̄)ᵀ`` rather than the
algebraically equal ``E[ppᵀ] − p̄p̄ᵀ`` to avoid cancellation in float32; it is symmetric
positive semi-definite by construction.
"""
from __future__ import annotations

import torch


def candidate_weights(volume: torch.Tensor, beta: float) -> torch.Tensor:
    """float[B, K·N·N]: ``softmax(β·C)`` over all candidates of each volume [B, K, N, N]."""
    return torch.softmax(beta * volume.flatten(1), dim=1)


def weighted_mean(weights: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """float[B, 3]: ``Σ ω p`` for weights [B, S] and candidates [S, 3]."""
    return weights @ candidates


def weighted_covariance(weights: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """float[B, 3, 3]: ``Σ ω (p − p̄)(p − p̄)ᵀ`` for weights [B, S] and candidates [S, 3]."""
    centred = candidates.unsqueeze(0) - weighted_mean(weights, candidates).unsqueeze(1)
    return (centred * weights.unsqueeze(-1)).transpose(1, 2) @ centred


def peak_window(volume: torch.Tensor, x_m: torch.Tensor, y_m: torch.Tensor, yaw_rad: torch.Tensor,
                half_m: float, half_rad: float) -> torch.Tensor:
    """float[B, K, N, N] 0/1 window of the candidates within ``±half_m`` (x and y) and ``±half_rad``
    (yaw) of each volume's best candidate.

    ``x_m``, ``y_m`` float[N] are the volume's translation axes (dims 2 and 3) and ``yaw_rad``
    float[K] or float[B, K] its yaws (dim 1; per batch item in the band search). Written with
    ArgMax, integer arithmetic and comparisons so it exports to every runtime.
    """
    b, k, n, _ = volume.shape
    best = volume.flatten(1).argmax(dim=1)  # [B]
    kk = torch.div(best, n * n, rounding_mode="floor")
    rest = best - kk * (n * n)
    ii = torch.div(rest, n, rounding_mode="floor")
    jj = rest - ii * n
    yaws = yaw_rad if yaw_rad.dim() == 2 else yaw_rad.unsqueeze(0).expand(b, k)
    yaw_best = torch.gather(yaws, 1, kk.unsqueeze(1))  # [B, 1]
    in_k = ((yaws - yaw_best).abs() <= half_rad).to(volume.dtype)  # [B, K]
    in_i = ((x_m.unsqueeze(0) - x_m[ii].unsqueeze(1)).abs() <= half_m).to(volume.dtype)  # [B, N]
    in_j = ((y_m.unsqueeze(0) - y_m[jj].unsqueeze(1)).abs() <= half_m).to(volume.dtype)
    return in_k[:, :, None, None] * in_i[:, None, :, None] * in_j[:, None, None, :]


def windowed_weights(volume: torch.Tensor, beta: float, window: torch.Tensor | None) -> torch.Tensor:
    """``softmax(β·C)`` [B, K, N, N], restricted to ``window`` (see `peak_window`) and renormalised
    when one is given: the pose then interpolates between the cells around the peak instead of
    averaging every distant candidate (which pulls a global soft-argmax towards the window's
    centre, i.e. towards zero motion, whenever the volume is not sharply peaked)."""
    w = candidate_weights(volume, beta).reshape(volume.shape)
    if window is None:
        return w
    w = w * window
    return w / w.sum(dim=(1, 2, 3), keepdim=True).clamp_min(1e-30)


def pose_window(profile) -> tuple[float, float] | None:
    """(half_m, half_rad) of the profile's local pose window, or None for the paper's global one."""
    c = getattr(profile, "pose_window_cells", 0)
    if not c:
        return None
    eps = 1e-6
    return c * profile.resolution_m + eps, c * profile.rotation_step_rad + eps


def soft_argmax(volume: torch.Tensor, candidates: torch.Tensor, beta: float,
                beta_cov: float | None = None, window: tuple[float, float] | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Pose mean float[B, 3] and covariance float[B, 3, 3] from a volume float[B, K, N, N].

    ``candidates`` is float[K, N, N, 3] (x m, y m, yaw rad), laid out like the volume (see
    ``correlation.candidate_poses``). ``beta`` weights the pose; ``beta_cov`` (default: the
    same) weights the covariance. ``window`` (half_m, half_rad), if given, restricts the pose's
    weights to the candidates around the best one (`peak_window`); the covariance always uses
    every candidate, so an ambiguous volume still says so.
    """
    flat = candidates.reshape(-1, 3)
    if window is not None:
        mask = peak_window(volume, candidates[0, :, 0, 0], candidates[0, 0, :, 1], candidates[:, 0, 0, 2],
                           window[0], window[1])
        mean = weighted_mean(windowed_weights(volume, beta, mask).flatten(1), flat)
        return mean, weighted_covariance(candidate_weights(volume, beta if beta_cov is None else beta_cov), flat)
    mean = weighted_mean(candidate_weights(volume, beta), flat)
    cov_weights = candidate_weights(volume, beta if beta_cov is None else beta_cov)
    return mean, weighted_covariance(cov_weights, flat)


def hard_argmax(volume: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """float[B, 3]: the single best candidate of each volume (no gradient; for evaluation)."""
    best = volume.flatten(1).argmax(dim=1)
    return candidates.reshape(-1, 3)[best]


def parabolic_peak(volume: torch.Tensor, x_m: torch.Tensor, y_m: torch.Tensor, yaw_rad: torch.Tensor,
                   yaw_step_rad: float) -> torch.Tensor:
    """float[B, 3]: the best candidate refined to sub-cell precision by a parabola through it and
    its two neighbours along each axis (x, y, yaw) of a volume float[B, K, N, N].

    ``x_m``, ``y_m`` float[N] are the translation axes (dims 2, 3), ``yaw_rad`` float[K] or
    [B, K] the yaws of dim 1; a yaw neighbour counts only if it lies one ``yaw_step_rad`` away
    (in the band search the slices need not be contiguous). The offset along an axis is
    ``(c₋ − c₊) / (2 (c₋ − 2c₀ + c₊))`` cells, clipped to ±½, and 0 where the peak sits on the
    border or the parabola does not curve down. Unlike the soft-argmax it depends on ratios of
    differences of C only, so the sweep's content (how many pixels match, hence the height of C)
    does not change how far between cells the pose can move.
    """
    b, k, n, _ = volume.shape
    flat = volume.flatten(1)
    best = flat.argmax(dim=1, keepdim=True)  # [B, 1]
    kk = torch.div(best, n * n, rounding_mode="floor")
    rest = best - kk * (n * n)
    ii = torch.div(rest, n, rounding_mode="floor")
    jj = rest - ii * n
    c0 = torch.gather(flat, 1, best)
    size = k * n * n

    def offset(stride: int, valid: torch.Tensor) -> torch.Tensor:
        lo = torch.gather(flat, 1, (best - stride).clamp(0, size - 1))
        hi = torch.gather(flat, 1, (best + stride).clamp(0, size - 1))
        den = lo - 2 * c0 + hi
        ok = valid & (den < 0)
        safe = torch.where(ok, den, -torch.ones_like(den))
        return torch.where(ok, (0.5 * (lo - hi) / safe).clamp(-0.5, 0.5), torch.zeros_like(den))

    yaws = yaw_rad if yaw_rad.dim() == 2 else yaw_rad.unsqueeze(0).expand(b, k)
    y0 = torch.gather(yaws, 1, kk)
    y_lo = torch.gather(yaws, 1, (kk - 1).clamp(0, k - 1))
    y_hi = torch.gather(yaws, 1, (kk + 1).clamp(0, k - 1))
    tol = 1e-3 * yaw_step_rad
    k_ok = ((kk > 0) & (kk < k - 1) & ((y0 - y_lo - yaw_step_rad).abs() < tol)
            & ((y_hi - y0 - yaw_step_rad).abs() < tol))
    o_i = offset(n, (ii > 0) & (ii < n - 1))
    o_j = offset(1, (jj > 0) & (jj < n - 1))
    o_k = offset(n * n, k_ok)
    dx = x_m[1] - x_m[0]
    dy = y_m[1] - y_m[0]
    return torch.cat([x_m[ii] + o_i * dx, y_m[jj] + o_j * dy, y0 + o_k * yaw_step_rad], dim=1)


def read_pose(volume: torch.Tensor, candidates: torch.Tensor, profile) -> torch.Tensor:
    """float[B, 3]: the pose a model with ``profile`` reads off volumes float[B, K, N, N] laid out
    like ``candidates`` float[K, N, N, 3]: the parabolic sub-cell peak, or the ``beta_pose``
    soft-argmax within the profile's pose window (`pose_window`; every candidate without one).
    The one definition training, export and calibration share."""
    c = candidates.to(volume.dtype)
    if profile.pose_estimator == "parabolic":
        return parabolic_peak(volume, c[0, :, 0, 0], c[0, 0, :, 1], c[:, 0, 0, 2], profile.rotation_step_rad)
    window = pose_window(profile)
    mask = None if window is None else peak_window(volume, c[0, :, 0, 0], c[0, 0, :, 1], c[:, 0, 0, 2], *window)
    return weighted_mean(windowed_weights(volume, profile.beta_pose, mask).flatten(1), c.reshape(-1, 3))

