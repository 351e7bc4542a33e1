import math

import pytest
import torch

from se3net.se3 import exp_so3

torch.manual_seed(0)


@pytest.mark.parametrize("scale", [0.0, 1e-5, 0.3, 2.5])
def test_exp_so3_is_a_rotation_with_the_right_angle(scale):
    w = torch.randn(16, 3, dtype=torch.float64)
    w = w / w.norm(dim=-1, keepdim=True) * scale
    R = exp_so3(w)
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(R @ R.transpose(-1, -2), eye.expand(16, 3, 3))
    angle = torch.arccos(((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1))
    torch.testing.assert_close(
        angle, torch.full((16,), scale, dtype=torch.float64), atol=1e-6, rtol=0
    )
    if scale > 0:  # the axis is fixed by the rotation
        torch.testing.assert_close((R @ w[..., None])[..., 0], w)


def test_exp_so3_matches_rodrigues_about_z():
    R = exp_so3(torch.tensor([0.0, 0.0, math.pi / 3], dtype=torch.float64))
    c, s = math.cos(math.pi / 3), math.sin(math.pi / 3)
    torch.testing.assert_close(
        R, torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1.0]], dtype=torch.float64)
    )


@pytest.mark.parametrize("scale", [0.0, 1e-4, 1.0])
def test_exp_so3_gradients_match_numeric_ones(scale):
    w = (torch.randn(4, 3, dtype=torch.float64) * scale).requires_grad_()
    assert torch.autograd.gradcheck(exp_so3, (w,))
