"""The paper's metric and what its figures showed: flow MSE, mask binariness, IoU.

Flow MSE (paper, Table 1): squared error between predicted and true 3D flow, averaged over
the points whose true flow is non-zero (here: above 0.1 mm, and still visible at the target
time), reported in cm^2 beside the no-motion baseline's error (the mean squared true flow).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from sim.dataset import MOVED_M, NONZERO_FLOW_M


def moving_points(
    points: torch.Tensor,
    target: torch.Tensor,
    target_valid: torch.Tensor,
    true_flow_m: torch.Tensor | None = None,
) -> torch.Tensor:
    """(B,H,W) bool: points whose true flow is non-zero and whose target is visible.

    ``true_flow_m`` (B,H,W): how far each point truly moves, from the noise-free data (a
    batch's ``true_flow_m``); without it, the flow from ``points`` to ``target``. Under the
    paper's noise the two differ: noisy points and targets differ nearly everywhere, so the
    noisy flow would count nearly every point as moving."""
    flow = (target - points).norm(dim=1) if true_flow_m is None else true_flow_m
    return target_valid & (flow > NONZERO_FLOW_M)


def true_flow(b: dict[str, torch.Tensor], h: int) -> torch.Tensor | None:
    """A batch's noise-free flow of step h (``PushDataset``'s ``true_flow_m``), which decides
    which points move; None for a batch made without it (the flow of its targets decides)."""
    flow = b.get("true_flow_m")
    return None if flow is None else flow[:, h]


def point_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    target_valid: torch.Tensor,
    points: torch.Tensor,
    *,
    true_flow_m: torch.Tensor | None = None,
) -> torch.Tensor:
    """Training loss (cm^2), on the squared error of predicted vs target points over visible
    targets, summed over every visible target and divided by the number of points that really
    move (at least 1), so that the few moving points are not drowned by the static background;
    static points still weigh as much each as moving ones, so a net that cannot tell them
    apart is paid to shrink every motion.
    """
    sq = ((pred - target) ** 2).sum(1) * target_valid
    moving = moving_points(points, target, target_valid, true_flow_m)
    return 1e4 * sq.sum() / moving.sum().clamp_min(1)


@dataclass
class FlowStats:
    """Accumulates the paper's flow MSE and the no-motion baseline's over batches."""

    sq_err: float = 0.0
    sq_flow: float = 0.0
    n: int = 0

    def add(
        self,
        pred: torch.Tensor,
        points: torch.Tensor,
        target: torch.Tensor,
        target_valid: torch.Tensor,
        true_flow_m: torch.Tensor | None = None,
    ) -> None:
        m = moving_points(points, target, target_valid, true_flow_m)
        self.sq_err += float(((pred - target) ** 2).sum(1)[m].sum())
        self.sq_flow += float(((target - points) ** 2).sum(1)[m].sum())
        self.n += int(m.sum())

    @property
    def mse_cm2(self) -> float:
        return self.sq_err / max(self.n, 1) * 1e4

    @property
    def no_motion_cm2(self) -> float:
        return self.sq_flow / max(self.n, 1) * 1e4

    @property
    def ratio(self) -> float:
        return self.sq_err / max(self.sq_flow, 1e-30)


@dataclass
class MaskStats:
    """Mask binariness and IoU with the true parts, over the bodies that move.

    For every example and every body other than the static world (the pusher, the objects)
    whose true flow exceeds 1 mm somewhere: binariness is the mean over its points of the
    largest mask weight; IoU is that of its true region with the best-matching argmax mask.
    The static world is left out: several near-identity masks may share it harmlessly.
    """

    max_weight_sum: float = 0.0
    n_points: int = 0
    iou_sum: float = 0.0
    n_bodies: int = 0

    def add(
        self,
        masks: torch.Tensor,
        part: torch.Tensor,
        points: torch.Tensor,
        target: torch.Tensor,
        true_flow_m: torch.Tensor | None = None,
    ) -> None:
        """``true_flow_m``: which bodies move, from the noise-free data (``moving_points``)."""
        flow = (target - points).norm(dim=1) if true_flow_m is None else true_flow_m
        label = masks.argmax(1)
        max_w = masks.max(1).values
        k = masks.shape[1]
        for b in range(part.shape[0]):
            for p in part[b].unique().tolist():
                region = part[b] == p
                if p < 1 or flow[b][region].max() <= MOVED_M:
                    continue
                self.max_weight_sum += float(max_w[b][region].sum())
                self.n_points += int(region.sum())
                valid = part[b] >= 0
                ious = []
                for c in range(k):
                    a = (label[b] == c) & valid
                    union = (a | region).sum()
                    ious.append(float((a & region).sum() / union) if union else 0.0)
                self.iou_sum += max(ious)
                self.n_bodies += 1

    @property
    def binariness(self) -> float:
        return self.max_weight_sum / max(self.n_points, 1)

    @property
    def iou(self) -> float:
        return self.iou_sum / max(self.n_bodies, 1)


def spearman(x: np.ndarray | list[float], y: np.ndarray | list[float]) -> float:
    """Spearman rank correlation (average ranks for ties)."""
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)
