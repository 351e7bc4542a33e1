import dataclasses

import pytest
import torch

from se3net.model import (
    VARIANTS,
    ModelConfig,
    build_model,
    n_parameters,
    sharpen,
    sharpening,
    transform_layer,
)
from se3net.se3 import params_to_transform


def _cloud(B=2, H=32, W=32):
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(B, 3, H, W, generator=g) * 0.1 + torch.tensor([0.0, 0.0, 0.8])[:, None, None]
    valid = torch.rand(B, H, W, generator=g) > 0.1
    return pts * valid[:, None], valid


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_variant_starts_by_predicting_no_motion(variant):
    cfg = ModelConfig(variant=variant, height=64, width=64)
    model = build_model(cfg).eval()
    pts, valid = _cloud(3, 64, 64)
    with torch.no_grad():
        pred = model(pts, torch.randn(3, 4), valid)
    torch.testing.assert_close(pred.points, pts, atol=1e-6, rtol=0)


def test_parameter_counts():
    small = n_parameters(build_model(ModelConfig("se3net")))
    assert 0.8e6 < small < 1.3e6  # "about 1 M parameters at 64x64"
    assert n_parameters(build_model(ModelConfig("se3net-large"))) > 2.5 * small
    assert n_parameters(build_model(ModelConfig("flow"))) == pytest.approx(small, rel=0.1)


def test_transform_layer_gradients_match_numeric_ones():
    B, k, H, W = 1, 3, 4, 5
    pts, valid = _cloud(B, H, W)
    pts = pts.double().requires_grad_()
    logits = torch.randn(B, k, H, W, dtype=torch.float64, requires_grad=True)
    params = (0.2 * torch.randn(B, k, 6, dtype=torch.float64)).requires_grad_()

    def f(p, lg, pr):
        return transform_layer(p, valid, torch.softmax(lg, 1), params_to_transform(pr))[0]

    assert torch.autograd.gradcheck(f, (pts, logits, params))


def test_transform_layer_applies_a_rigid_motion_to_a_binary_mask():
    pts, valid = _cloud(1, 8, 8)
    pts, valid[:] = pts.double(), True
    masks = torch.zeros(1, 2, 8, 8, dtype=torch.float64)
    masks[:, 0, :4], masks[:, 1, 4:] = 1, 1
    T = params_to_transform(
        torch.tensor([[[0, 0, 0, 0, 0, 0], [0.01, 0.02, 0, 0, 0, 0.3]]], dtype=torch.float64)
    )
    y, piv = transform_layer(pts, valid, masks, T)
    torch.testing.assert_close(y[:, :, :4], pts[:, :, :4])
    moved = y[0, :, 4:].reshape(3, -1).T
    src = pts[0, :, 4:].reshape(3, -1).T
    # a rigid motion keeps distances
    torch.testing.assert_close(torch.cdist(moved, moved), torch.cdist(src, src), atol=1e-5, rtol=0)
    # about the mask's centroid, the centroid moves by the translation alone
    translation = torch.tensor([0.01, 0.02, 0], dtype=torch.float64)
    torch.testing.assert_close(moved.mean(0), src.mean(0) + translation, atol=1e-6, rtol=0)


def test_sharpening_drives_masks_towards_binary():
    g = torch.Generator().manual_seed(0)
    masks = torch.softmax(torch.randn(64, 4, 8, 8, generator=g), 1)
    plain = masks.max(1).values.mean()
    sharp = sharpen(masks, 0.0, 30.0).max(1).values.mean()
    noisy = sharpen(masks, 0.1, 30.0, torch.Generator().manual_seed(1)).max(1).values.mean()
    assert plain < 0.7 and sharp > 0.95 and noisy > 0.9
    torch.testing.assert_close(sharpen(masks, 0.1, 30.0).sum(1), torch.ones(64, 8, 8))
    cfg = ModelConfig()
    assert sharpening(0, 1000, cfg) == (0.0, 1.0)
    assert sharpening(1000, 1000, cfg) == (cfg.sigma_max, cfg.gamma_max)
    sig, gam = sharpening(250, 1000, cfg)
    assert 0 < sig < cfg.sigma_max and 1 < gam < cfg.gamma_max
    assert sharpening(1000, 1000, dataclasses.replace(cfg, variant="no-penalty")) == (0.0, 1.0)


def test_bad_configs_are_refused():
    with pytest.raises(ValueError, match="unknown variant 'big'.*se3net-large"):
        ModelConfig(variant="big")
    with pytest.raises(ValueError, match="divisible by 32"):
        ModelConfig(variant="se3net-large", height=48, width=48)


@pytest.mark.parametrize("variant", ["se3net", "flow"])
def test_one_encoding_serves_a_batch_of_controls(variant):
    # the planner encodes the observed cloud once for all its action sequences: exactly
    torch.manual_seed(0)
    model = build_model(ModelConfig(variant=variant, height=32, width=32)).eval()
    for p in model.parameters():  # away from the identity start, so every path matters
        p.data.add_(0.05 * torch.randn_like(p))
    pts, valid = _cloud(1, 32, 32)
    u = torch.randn(5, 4)
    with torch.no_grad():
        once = model.predict(pts, u, valid, model.encode(pts, valid)).points
        each = model(pts.expand(5, -1, -1, -1), u, valid.expand(5, -1, -1)).points
    torch.testing.assert_close(once, each, atol=1e-5, rtol=1e-5)
    assert (once[0] - once[1]).abs().max() > 1e-4  # the controls matter


@pytest.mark.parametrize("variant", ["se3net", "flow"])
def test_a_rollout_from_one_observed_cloud_is_that_of_the_cloud_repeated(variant):
    # the planner's rollout: one observed cloud and its validity, B action sequences, the
    # predicted clouds fed back (batch B) beside the observed validity (batch 1)
    from se3net.rollout import rollout

    torch.manual_seed(0)
    model = build_model(ModelConfig(variant=variant, height=32, width=32)).eval()
    for p in model.parameters():
        p.data.add_(0.05 * torch.randn_like(p))
    pts, valid = _cloud(1, 32, 32)
    actions, pusher = 0.05 * torch.randn(4, 3, 2), torch.tensor([[0.1, -0.05]])
    with torch.no_grad():
        once = rollout(model, pts, valid, actions, pusher, 0.15)
        each = rollout(
            model, pts.expand(4, -1, -1, -1), valid.expand(4, -1, -1), actions,
            pusher.expand(4, -1), 0.15,
        )  # fmt: skip
    for a, b in zip(once, each, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)


def test_a_checkpoint_of_retired_options_loads_only_where_it_did_not_use_them(tmp_path):
    """FiLM controls, a validity channel and a full-resolution head were tried and not kept: a
    checkpoint that stored them unused loads; one that used them is refused, naming them and
    the commit that can load it."""
    from se3net.checkpoint import CheckpointError, _config_of

    stored = {"variant": "flow", "k": 4, "height": 32, "width": 32, "control_dim": 4}
    unused = {"controls": "fused", "valid_channel": False, "full_res_head": False}
    assert _config_of({"model": {**stored, **unused}}, "x.pt") == ModelConfig(**stored)
    with pytest.raises(CheckpointError, match=r"controls=film.*commit c7fec27"):
        _config_of({"model": {**stored, **unused, "controls": "film"}}, "x.pt")
