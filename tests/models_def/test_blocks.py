"""Blocks and norms: behaviour, bad inputs, and float64 gradcheck (kornia-style op tests)."""

from __future__ import annotations

import math

import pytest
import torch

from models_def.blocks import BlurPool2d, DownResBlock, EqualConv2d, EqualLinear
from models_def.generator import SpadeResBlock
from models_def.norms import SPADE, AdaIN, SpadeConditionProjection, instance_norm


def _gen() -> torch.Generator:
    return torch.Generator().manual_seed(0)


def _rand(*shape: int, dtype=torch.float64) -> torch.Tensor:
    return torch.randn(*shape, generator=_gen(), dtype=dtype)


class TestEqualised:
    def test_weights_are_unit_normal_and_scaled_at_run_time(self):
        torch.manual_seed(0)
        conv = EqualConv2d(64, 32, 3)
        assert conv.scale == pytest.approx(1 / math.sqrt(64 * 9))
        assert abs(conv.weight.std().item() - 1.0) < 0.05
        x = torch.randn(2, 64, 8, 8)
        expected = torch.nn.functional.conv2d(x, conv.weight * conv.scale, conv.bias, padding=1)
        torch.testing.assert_close(conv(x), expected)
        linear = EqualLinear(16, 8, bias_init=1.0)
        torch.testing.assert_close(linear.bias, torch.ones(8))
        assert linear.scale == pytest.approx(0.25)

    def test_output_variance_is_preserved(self):
        torch.manual_seed(0)
        conv = EqualConv2d(128, 128, 3)
        out = conv(torch.randn(4, 128, 16, 16))[:, :, 1:-1, 1:-1]
        assert 0.8 < out.var().item() < 1.2

    def test_gradcheck(self):
        conv = EqualConv2d(3, 4, 3, stride=2).double()
        assert torch.autograd.gradcheck(conv, (_rand(1, 3, 5, 5).requires_grad_(),))
        linear = EqualLinear(5, 3).double()
        assert torch.autograd.gradcheck(linear, (_rand(2, 5).requires_grad_(),))


class TestBlurPool:
    def test_shape_and_constant_preserved(self):
        pool = BlurPool2d(3)
        assert pool(torch.zeros(2, 3, 9, 8)).shape == (2, 3, 5, 4)
        constant = torch.full((1, 3, 8, 8), 0.7)
        torch.testing.assert_close(pool(constant), torch.full((1, 3, 4, 4), 0.7))

    def test_kernel_not_in_state_dict(self):
        assert "kernel" not in BlurPool2d(4).state_dict()

    def test_antialiasing_removes_nyquist_checkerboard(self):
        checker = (torch.arange(8)[:, None] + torch.arange(8)[None, :]) % 2
        out = BlurPool2d(1)(checker.float().view(1, 1, 8, 8))
        assert out[..., 1:-1, 1:-1].std() < 1e-6  # plain strided sampling would keep all ones

    def test_gradcheck(self):
        pool = BlurPool2d(2).double()
        assert torch.autograd.gradcheck(pool, (_rand(1, 2, 6, 6).requires_grad_(),))
        block = DownResBlock(2, 3).double()
        assert torch.autograd.gradcheck(block, (_rand(1, 2, 4, 4).requires_grad_(),))


class TestNorms:
    def test_instance_norm_of_constant_is_zero_not_nan(self):
        for dtype in (torch.float32, torch.bfloat16, torch.float16):
            out = instance_norm(torch.full((1, 2, 4, 4), 3.0, dtype=dtype))
            assert out.dtype == dtype and out.abs().max() < 1e-3  # exact 0 up to the rounding of the mean

    def test_instance_norm_half_statistics_in_float32(self):
        x = (torch.randn(1, 2, 16, 16) * 1e4).half()
        out = instance_norm(x)
        assert torch.isfinite(out).all()
        torch.testing.assert_close(out.float(), instance_norm(x.float()), atol=2e-2, rtol=1e-2)

    def test_adain_initial_identity_and_gradcheck(self):
        norm = AdaIN(3, 5).double()
        x, latent = _rand(2, 3, 4, 4), torch.zeros(2, 5, dtype=torch.float64)
        torch.testing.assert_close(norm(x, latent), instance_norm(x))
        assert torch.autograd.gradcheck(norm, (x.requires_grad_(), _rand(2, 5).requires_grad_()))

    def test_spade_gradcheck(self):
        projection = SpadeConditionProjection(4, 3).double()
        norm = SPADE(2, 3).double()

        def spade(x, condition):
            return norm(x, projection(condition))

        inputs = (_rand(1, 2, 4, 4).requires_grad_(), _rand(1, 4, 4, 4).requires_grad_())
        assert torch.autograd.gradcheck(spade, inputs)

    @pytest.mark.parametrize("shared", [False, True])
    def test_spade_res_block_gradcheck_and_shared_modulation(self, shared):
        block = SpadeResBlock(3, 2, cond_channels=4, hidden_channels=3, eps=1e-5, shared_input_modulation=shared)
        assert (block.norm_s is None) == shared
        inputs = (_rand(1, 3, 4, 4).requires_grad_(), _rand(1, 4, 4, 4).requires_grad_())
        assert torch.autograd.gradcheck(block.double(), inputs)


def test_channel_softmax_is_the_softmax_over_channels_and_stays_finite():
    from models_def.blocks import channel_softmax

    x = _rand(2, 19, 9, 7)
    torch.testing.assert_close(channel_softmax(x), x.softmax(dim=1), atol=1e-12, rtol=1e-12)
    large = channel_softmax(x.float() * 1e4)  # exp of the raw logits would overflow
    assert torch.isfinite(large).all()
    torch.testing.assert_close(large.sum(dim=1), torch.ones(2, 9, 7), atol=1e-6, rtol=0)

