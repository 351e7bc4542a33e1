"""SE(3) utilities in torch: the exponential map, and 6-vector parameters to transforms.

Transforms are ``(...,3,4)`` matrices ``[R | t]`` acting on points ``(...,N,3)``. Everything is
batched and differentiable; the exponential map is exact and smooth at theta = 0 (Taylor
expansions below a small angle, with the division guarded so that gradients stay finite).
"""

from __future__ import annotations

import torch

SMALL_ANGLE_SQ = 1e-6


def skew(w: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices ``(...,3,3)`` of vectors ``(...,3)``."""
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*w.shape[:-1], 3, 3)


def exp_so3(w: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``(...,3,3)`` of axis-angle vectors ``(...,3)`` (Rodrigues' formula,
    ``R = I + A K + B K^2`` with ``A = sin(t)/t``, ``B = (1 - cos t)/t^2``)."""
    theta_sq = (w * w).sum(-1)
    small = theta_sq < SMALL_ANGLE_SQ
    safe_sq = torch.where(small, torch.ones_like(theta_sq), theta_sq)
    theta = safe_sq.sqrt()
    A = torch.where(small, 1 - theta_sq / 6 + theta_sq**2 / 120, torch.sin(theta) / theta)
    B = torch.where(
        small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, (1 - torch.cos(theta)) / safe_sq
    )
    K = skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand(K.shape)
    return eye + A[..., None, None] * K + B[..., None, None] * (K @ K)


def params_to_transform(params: torch.Tensor) -> torch.Tensor:
    """``(...,6)`` parameters ``[translation (3), axis-angle (3)]`` (the authors' order) to
    transforms ``(...,3,4)``."""
    return torch.cat([exp_so3(params[..., 3:]), params[..., :3, None]], -1)
