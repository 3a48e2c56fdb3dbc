"""The train stage's speed-ups compute what the stock code computes: ACT's one-pixel convolutions
as matrix products (forward and gradients, up to rounding), and gradient clipping that rescales
only gradients over the limit (the same gradients, to the bit)."""

from __future__ import annotations

import copy

import pytest
import torch
import torchvision
from torchvision.models._utils import IntermediateLayerGetter
from torchvision.ops.misc import FrozenBatchNorm2d

from r2s_eval.policies.train import clip_gradients
from r2s_eval.policies.types.act import single_output_convolutions


def _backbone():
    torch.manual_seed(0)
    resnet = torchvision.models.resnet18(weights=None, norm_layer=FrozenBatchNorm2d)
    return IntermediateLayerGetter(resnet, return_layers={"layer4": "feature_map"})


def _forward_backward(model, images):
    for p in model.parameters():
        p.grad = None
    out = model(images)["feature_map"]
    (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
    return out.detach(), {name: p.grad.clone() for name, p in model.named_parameters()}


@pytest.mark.parametrize("side", [32, 48])  # 32 px: layer4's maps are one pixel; 48 px: two (stock path)
def test_one_pixel_convolutions_compute_the_stock_function_and_gradients(side):
    stock, fast = _backbone(), _backbone()
    images = torch.rand(4, 3, side, side, generator=torch.Generator().manual_seed(1))
    want, want_grads = _forward_backward(stock, images)
    with single_output_convolutions(fast):
        got, got_grads = _forward_backward(fast, images)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5 * float(want.abs().max()))
    for name, grad in want_grads.items():
        torch.testing.assert_close(got_grads[name], grad, rtol=1e-4, atol=1e-5 * float(grad.abs().max()) + 1e-12)
    # The taps a one-pixel map never meets get no gradient, as in the stock convolution.
    if side == 32:
        assert float(got_grads["layer4.1.conv1.weight"][:, :, 0, 0].abs().max()) == 0.0


def test_the_model_is_stock_again_after_training():
    model = _backbone()
    keys = list(model.state_dict())
    with single_output_convolutions(model):
        pass
    assert list(model.state_dict()) == keys
    assert not any("forward" in vars(m) for m in model.modules())


def test_clipping_leaves_gradients_under_the_limit_untouched_and_scales_those_over_it():
    for max_norm in (1e3, 0.5):
        stock, ours = torch.nn.Linear(8, 4), torch.nn.Linear(8, 4)
        ours.load_state_dict(stock.state_dict())
        x = torch.randn(16, 8, generator=torch.Generator().manual_seed(2))
        for model in (stock, ours):
            model(x).pow(2).sum().backward()
        want = torch.nn.utils.clip_grad_norm_(stock.parameters(), max_norm)
        got = clip_gradients(ours, max_norm)
        assert float(got) == float(want)
        for a, b in zip(stock.parameters(), ours.parameters()):
            assert torch.equal(a.grad, b.grad)
