"""SE(3) utilities in torch: exponential map, composition, inverse, weighted rigid fit.

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


def compose(T_ab: torch.Tensor, T_bc: torch.Tensor) -> torch.Tensor:
    """``T_ac = T_ab · T_bc`` for transforms ``(...,3,4)``."""
    R = T_ab[..., :3] @ T_bc[..., :3]
    t = (T_ab[..., :3] @ T_bc[..., 3:]) + T_ab[..., 3:]
    return torch.cat([R, t], -1)


def inverse(T: torch.Tensor) -> torch.Tensor:
    """Inverse of transforms ``(...,3,4)``."""
    Rt = T[..., :3].transpose(-1, -2)
    return torch.cat([Rt, -(Rt @ T[..., 3:])], -1)


def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Apply transforms ``(...,3,4)`` to points ``(...,N,3)``."""
    return points @ T[..., :3].transpose(-1, -2) + T[..., None, :, 3]


def rigid_fit(src: torch.Tensor, dst: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Weighted least-squares rigid transform (Kabsch) taking ``src`` to ``dst``.

    Args:
        src, dst: (...,N,3) corresponding points.
        weights: (...,N) non-negative weights (at least three non-collinear points with
            positive weight for a unique rotation).

    Returns:
        (...,3,4) the transform minimising ``sum_j w_j |R src_j + t - dst_j|^2``.
    """
    w = weights / weights.sum(-1, keepdim=True).clamp_min(1e-12)
    mu_s = (w[..., None] * src).sum(-2)
    mu_d = (w[..., None] * dst).sum(-2)
    cov = ((dst - mu_d[..., None, :]) * w[..., None]).transpose(-1, -2) @ (src - mu_s[..., None, :])
    U, _, Vh = torch.linalg.svd(cov)
    d = torch.det(U @ Vh).sign()
    d = torch.where(d == 0, torch.ones_like(d), d)
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    R = U @ D @ Vh
    t = mu_d - (R @ mu_s[..., None])[..., 0]
    return torch.cat([R, t[..., None]], -1)
