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


def soft_argmax(volume: torch.Tensor, candidates: torch.Tensor, beta: float,
                beta_cov: float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Pose mean float[B, 3] and covariance float[B, 3, 3] from a volume float[B, K, N, N].

    ``candidates`` is float[K, N, N, 3] (x m, y m, yaw rad), laid out like the volume (see
    ``correlation.candidate_poses``). ``beta`` weights the pose; ``beta_cov`` (default: the
    same) weights the covariance.
    """
    flat = candidates.reshape(-1, 3)
    mean = weighted_mean(candidate_weights(volume, beta), flat)
    cov_weights = candidate_weights(volume, beta if beta_cov is None else beta_cov)
    return mean, weighted_covariance(cov_weights, flat)


def hard_argmax(volume: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """float[B, 3]: the single best candidate of each volume (no gradient; for evaluation)."""
    best = volume.flatten(1).argmax(dim=1)
    return candidates.reshape(-1, 3)[best]
