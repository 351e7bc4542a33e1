"""The SE3-Net (Byravan & Fox, 2017) and the paper's flow baselines, built from one config.

Encoder: conv blocks with BatchNorm and PReLU, strided (small) or with max-pooling (large);
control encoder: two FC layers; late fusion by concatenation, then FC. Decoders (masks for
the SE3-Net, flow for the baselines) are deconvolutions from the fused code that add the
matching encoder features (skip-add). The SE(3) head predicts k transforms, initialised to the
identity; the transform layer blends them with the masks (paper, Eq. 3):

    y_j = sum_i m_ij (R_i (x_j - c_i) + c_i + t_i)

with pivots ``c_i`` the mask-weighted centroid of the input points. The paper pivots about
the camera origin (``c_i = 0``); both span the same motions, but about the centroid the
translation is the mask's own motion, which trains better (docs/model.md); the origin was
tried and not kept (commit c7fec27 has it).

Weight sharpening (paper, Eq. 2): ``m' = normalise((m + eps)^gamma)``, ``eps ~ N(0, sigma^2)``,
with sigma and gamma ramped over training (``sharpening``); at evaluation the last gamma is
applied without noise, so the masks used are those the training ended with.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import NamedTuple

import torch
from torch import nn

from scenarios import InputError
from se3net.se3 import params_to_transform

VARIANTS = ("se3net", "se3net-large", "no-penalty", "flow", "flow-large")
FLOW_SCALE_M = 0.01
"""the flow decoder predicts flow in units of 1 cm"""


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of one variant."""

    variant: str = "se3net"
    """one of VARIANTS"""
    k: int = 4
    """number of masks and transforms (SE3-Net variants)"""
    height: int = 64
    """input height in pixels (a multiple of 16, of 32 for large variants)"""
    width: int = 64
    """input width in pixels"""
    control_dim: int = 4
    """length of the control vector u"""
    sigma_max: float = 0.1
    """largest SD of the sharpening noise"""
    gamma_max: float = 30.0
    """largest sharpening exponent"""
    stride: int = 1
    """the network sees every stride-th pixel of the camera's image in each direction
    (``se3net.data.subsample``): height and width are the camera's divided by it, a
    planning-resolution model (checkpoints from before it existed are stride 1)"""

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise InputError(f"unknown variant {self.variant!r}; known: {', '.join(VARIANTS)}")
        div = 32 if self.large else 16
        if self.height % div or self.width % div:
            raise InputError(f"{self.variant} needs height and width divisible by {div}")
        if self.k < 1 or self.control_dim < 1 or self.stride < 1:
            raise InputError("k, control_dim and stride must be positive")

    @property
    def large(self) -> bool:
        return self.variant.endswith("-large")

    @property
    def is_flow(self) -> bool:
        return self.variant.startswith("flow")

    @property
    def sharpens(self) -> bool:
        return self.variant in ("se3net", "se3net-large")

    def to_dict(self) -> dict:
        return asdict(self)


class Prediction(NamedTuple):
    """What a model predicts for a batch."""

    points: torch.Tensor
    """(B,3,H,W) predicted cloud"""
    masks: torch.Tensor | None
    """(B,k,H,W) masks used by the transform layer (None for flow nets)"""
    transforms: torch.Tensor | None
    """(B,k,3,4) SE(3) transforms about the pivots (None for flow nets)"""
    pivots: torch.Tensor | None
    """(B,k,3) rotation centres (None for flow nets)"""


class Encoding(NamedTuple):
    """What the network computes from a cloud alone (before the controls enter)."""

    feats: tuple[torch.Tensor, ...]
    """encoder features, finest first, each (B,C,h,w)"""
    z: torch.Tensor
    """(B,256) the cloud's code"""
    x: torch.Tensor
    """(B,3,H,W) the network's input: the normalised cloud, zero at pixels without a point"""


def _block(conv: nn.Module, channels: int, *, pool: bool = False) -> nn.Sequential:
    layers = (
        [conv]
        + ([nn.MaxPool2d(2)] if pool else [])
        + [nn.BatchNorm2d(channels), nn.PReLU(channels)]
    )
    return nn.Sequential(*layers)


class _Backbone(nn.Module):
    """Cloud encoder, control encoder, fusion and a skip-add deconvolution decoder."""

    SMALL = ((24, 5), (48, 3), (96, 3), (192, 3))
    LARGE = ((32, 9), (64, 7), (128, 5), (256, 3), (256, 3))
    CODE, REDUCED = 256, 32

    def __init__(self, cfg: ModelConfig, out_channels: int):
        super().__init__()
        spec = self.LARGE if cfg.large else self.SMALL
        chans = [c for c, _ in spec]
        enc, c_in = [], 3
        for c, k in spec:
            if cfg.large:
                enc.append(_block(nn.Conv2d(c_in, c, k, padding=k // 2), c, pool=True))
            else:
                enc.append(_block(nn.Conv2d(c_in, c, k, stride=2, padding=k // 2), c))
            c_in = c
        self.encoder = nn.ModuleList(enc)
        self.s_h, self.s_w = cfg.height >> len(spec), cfg.width >> len(spec)
        flat = self.REDUCED * self.s_h * self.s_w
        self.reduce = _block(nn.Conv2d(chans[-1], self.REDUCED, 1), self.REDUCED)
        self.cloud_fc = nn.Sequential(nn.Linear(flat, self.CODE), nn.PReLU())
        self.control = nn.Sequential(
            nn.Linear(cfg.control_dim, 64), nn.PReLU(), nn.Linear(64, 128), nn.PReLU()
        )
        self.fuse = nn.Sequential(nn.Linear(self.CODE + 128, self.CODE), nn.PReLU())
        self.expand_fc = nn.Sequential(nn.Linear(self.CODE, flat), nn.PReLU())
        self.expand = nn.Conv2d(self.REDUCED, chans[-1], 1)
        self.expand_act = nn.Sequential(nn.BatchNorm2d(chans[-1]), nn.PReLU(chans[-1]))
        ups, post = [], []
        for c_hi, c_lo in zip(chans[:0:-1], chans[-2::-1], strict=True):
            ups.append(nn.ConvTranspose2d(c_hi, c_lo, 4, stride=2, padding=1))
            post.append(nn.Sequential(nn.BatchNorm2d(c_lo), nn.PReLU(c_lo)))
        self.ups, self.post = nn.ModuleList(ups), nn.ModuleList(post)
        self.head = nn.ConvTranspose2d(chans[0], out_channels, 4, stride=2, padding=1)

    @property
    def out_layer(self) -> nn.Module:
        """The layer whose output is the prediction (a flow net starts it at zero)."""
        return self.head

    def encode(self, x: torch.Tensor) -> Encoding:
        """The cloud's half of the network: encoder features and the cloud code."""
        feats, y = [], x
        for block in self.encoder:
            y = block(y)
            feats.append(y)
        return Encoding(tuple(feats), self.cloud_fc(self.reduce(y).flatten(1)), x)

    def code(self, enc: Encoding, u: torch.Tensor) -> torch.Tensor:
        """(B,256) the fused code of an encoding (batch 1 or B) and normalised controls (B,n)."""
        z = enc.z.expand(len(u), -1)
        return self.fuse(torch.cat([z, self.control(u)], 1))

    def decode(self, code: torch.Tensor, enc: Encoding) -> torch.Tensor:
        """(B,out,H,W) the decoder's output: deconvolutions from the code, skip-adding the
        encoder's features (batch 1 or B)."""
        feats = enc.feats
        y = self.expand_fc(code).view(-1, self.REDUCED, self.s_h, self.s_w)
        y = self.expand_act(self.expand(y) + feats[-1])
        for up, post, skip in zip(self.ups, self.post, feats[-2::-1], strict=True):
            y = post(up(y) + skip)
        return self.head(y)


class _Normaliser(nn.Module):
    """Input and control normalisation, stored with the weights."""

    def __init__(self, control_dim: int):
        super().__init__()
        self.register_buffer("points_mean", torch.zeros(3))
        self.register_buffer("points_std", torch.ones(3))
        self.register_buffer("u_mean", torch.zeros(control_dim))
        self.register_buffer("u_std", torch.ones(control_dim))

    def points(self, points: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        x = (points - self.points_mean[:, None, None]) / self.points_std[:, None, None]
        return x * valid[:, None]

    def controls(self, u: torch.Tensor) -> torch.Tensor:
        return (u - self.u_mean) / self.u_std


def sharpen(
    masks: torch.Tensor, sigma: float, gamma: float, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Weight sharpening over dim 1: ``normalise(clamp(m + eps, 0)^gamma)`` (in log space)."""
    if sigma > 0:
        noise = torch.randn(
            masks.shape, generator=generator, device=masks.device, dtype=masks.dtype
        )
        masks = masks + sigma * noise
    if gamma == 1.0 and sigma == 0:
        return masks
    return torch.softmax(gamma * torch.log(masks.clamp_min(1e-12)), dim=1)


def transform_layer(
    points: torch.Tensor,
    valid: torch.Tensor,
    masks: torch.Tensor,
    T: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Blend k rigid motions with the masks (paper, Eq. 3).

    Args:
        points: (B,3,H,W) input cloud; valid: (B,H,W) bool; masks: (B,k,H,W), summing to 1
            over k; T: (B,k,3,4) transforms about the pivots, each mask's mask-weighted
            centroid.

    Returns:
        (B,3,H,W) ``y_j = sum_i m_ij (R_i (x_j - c_i) + c_i + t_i)`` (invalid pixels keep
        their input), and the pivots (B,k,3).
    """
    B, k = masks.shape[:2]
    x, m = points.flatten(2), masks.flatten(2)  # (B,3,N), (B,k,N)
    mv = m * valid.flatten(1)[:, None]
    pivots = (x @ mv.transpose(1, 2)).transpose(1, 2) / mv.sum(-1, keepdim=True).clamp_min(1e-6)
    R = T[..., :3]
    offset = pivots - (R @ pivots[..., None])[..., 0] + T[..., 3]  # (B,k,3)
    # each point's blended affine map sum_i m_ij [R_i | offset_i], then applied: a (12 x k)
    # by (k x N) product and 9 multiply-adds a point, not k rigid motions of every point
    A = torch.cat([R, offset[..., None]], -1).flatten(2)  # (B,k,12)
    blend = (A.transpose(1, 2) @ m).view(B, 3, 4, -1)  # (B,3,4,N)
    y = ((blend[:, :, :3] * x[:, None]).sum(2) + blend[:, :, 3]).view_as(points)
    return torch.where(valid[:, None], y, points), pivots


class _CloudNet(nn.Module):
    """What the SE3-Net and the flow net share: normalisation, the backbone, the encoding."""

    def __init__(self, cfg: ModelConfig, out_channels: int):
        super().__init__()
        self.cfg = cfg
        self.norm = _Normaliser(cfg.control_dim)
        self.backbone = _Backbone(cfg, out_channels)

    def encode(self, points: torch.Tensor, valid: torch.Tensor) -> Encoding:
        """The cloud's part of a prediction, for :meth:`predict` (once for many controls)."""
        return self.backbone.encode(self.norm.points(points, valid))


class SE3Net(_CloudNet):
    """SE3-Net: masks, SE(3) transforms and the transform layer."""

    def __init__(self, cfg: ModelConfig):
        super().__init__(cfg, cfg.k)
        self.se3_head = nn.Sequential(
            nn.Linear(_Backbone.CODE, 128), nn.PReLU(), nn.Linear(128, cfg.k * 6)
        )
        nn.init.zeros_(self.se3_head[-1].weight)  # every transform starts as the identity
        nn.init.zeros_(self.se3_head[-1].bias)
        self.register_buffer("gamma", torch.tensor(1.0))  # sharpening exponent used in eval

    def predict(
        self,
        points: torch.Tensor,
        u: torch.Tensor,
        valid: torch.Tensor,
        enc: Encoding,
        *,
        sigma: float = 0.0,
        gamma: float | None = None,
        generator: torch.Generator | None = None,
    ) -> Prediction:
        """Predict the cloud after one step from an encoding of ``points``.

        Args:
            points: (B0,3,H,W) input cloud, camera frame (m), B0 = 1 or B. u: (B,n) controls.
            valid: (B0,H,W) bool. enc: ``encode(points, valid)``.
            sigma, gamma: sharpening noise SD and exponent (training); by default no noise
                and the exponent training ended with.
        """
        code = self.backbone.code(enc, self.norm.controls(u))
        masks = torch.softmax(self.backbone.decode(code, enc), dim=1)
        if self.cfg.sharpens:
            g = float(self.gamma) if gamma is None else gamma
            masks = sharpen(masks, sigma, g, generator)
        B, k = masks.shape[:2]
        T = params_to_transform(self.se3_head(code).view(B, k, 6))  # (B,k,3,4)
        points, valid = points.expand(B, -1, -1, -1), valid.expand(B, -1, -1)
        y, pivots = transform_layer(points, valid, masks, T)
        return Prediction(y, masks, T, pivots)

    def forward(
        self,
        points: torch.Tensor,
        u: torch.Tensor,
        valid: torch.Tensor,
        *,
        sigma: float = 0.0,
        gamma: float | None = None,
        generator: torch.Generator | None = None,
    ) -> Prediction:
        """Predict the cloud after one step.

        Args:
            points: (B,3,H,W) input cloud, camera frame (m). u: (B,n) controls.
            valid: (B,H,W) bool, pixels that hold a point.
            sigma, gamma: sharpening noise SD and exponent (training); by default no noise
                and the exponent training ended with.
        """
        enc = self.encode(points, valid)
        return self.predict(points, u, valid, enc, sigma=sigma, gamma=gamma, generator=generator)


class FlowNet(_CloudNet):
    """The paper's flow baseline: a conv/deconv net that predicts per-point 3D flow."""

    def __init__(self, cfg: ModelConfig):
        super().__init__(cfg, 3)
        nn.init.zeros_(self.backbone.out_layer.weight)  # starts predicting no motion
        nn.init.zeros_(self.backbone.out_layer.bias)

    def predict(
        self,
        points: torch.Tensor,
        u: torch.Tensor,
        valid: torch.Tensor,
        enc: Encoding,
        **_: object,
    ) -> Prediction:
        """Predict the cloud after one step from an encoding of ``points`` (batch 1 or B)."""
        flow = self.backbone.decode(self.backbone.code(enc, self.norm.controls(u)), enc)
        B = len(flow)
        points, valid = points.expand(B, -1, -1, -1), valid.expand(B, -1, -1)
        y = torch.where(valid[:, None], points + FLOW_SCALE_M * flow, points)
        return Prediction(y, None, None, None)

    def forward(
        self, points: torch.Tensor, u: torch.Tensor, valid: torch.Tensor, **_: object
    ) -> Prediction:
        return self.predict(points, u, valid, self.encode(points, valid))


def build_model(cfg: ModelConfig) -> nn.Module:
    """The network for ``cfg.variant``."""
    return FlowNet(cfg) if cfg.is_flow else SE3Net(cfg)


def n_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def sharpening(it: int, iters: int, cfg: ModelConfig) -> tuple[float, float]:
    """(sigma, gamma) at iteration ``it`` of ``iters``: sigma ramps from 0 to its maximum
    over 80 % of the run, gamma from 1 to its maximum over the first half (the authors'
    schedule, scaled to the run's length); (0, 1) for variants without sharpening."""
    if not cfg.sharpens:
        return 0.0, 1.0
    sigma = cfg.sigma_max * min(1.0, it / max(1.0, 0.8 * iters))
    gamma = 1.0 + (cfg.gamma_max - 1.0) * min(1.0, it / max(1.0, 0.5 * iters))
    return sigma, gamma
