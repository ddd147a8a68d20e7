"""The project's Adam (fused) against torch's single-tensor Adam as the reference."""

from __future__ import annotations

import copy
from collections.abc import Iterator

import pytest
import torch

from shsas_core.common import optim


def _params(seed: int) -> list[torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=gen).requires_grad_(True) for shape in ((4096, 2), (32, 24), (32,), ())]


def _step(opt: torch.optim.Optimizer, params: list[torch.Tensor], seed: int) -> None:
    gen = torch.Generator().manual_seed(seed)
    for p in params:
        p.grad = torch.randn(p.shape, generator=gen)
    opt.step()


@pytest.fixture
def fused_flag() -> Iterator[None]:
    before = optim.FUSED
    yield
    optim.FUSED = before


def test_fused_adam_takes_the_single_tensor_steps(fused_flag: None) -> None:
    ref, ours = _params(0), _params(0)
    optim.FUSED = False
    single = optim.adam(ref, lr=1e-2)
    optim.FUSED = True
    fused = optim.adam(ours, lr=1e-2)
    assert fused.defaults["fused"] and not single.defaults["fused"]
    for i in range(20):
        _step(single, ref, i)
        _step(fused, ours, i)
    moved = max(float((a - b).detach().abs().max()) for a, b in zip(ref, _params(0), strict=True))
    assert moved > 0.1  # the steps did move the parameters
    for a, b in zip(ref, ours, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6)


def test_a_single_tensor_checkpoint_resumes_under_fused_adam(fused_flag: None) -> None:
    """A training checkpoint written before the switch holds a single-tensor Adam's state."""
    ref, ours = _params(1), _params(1)
    optim.FUSED = False
    single = optim.adam(ref, lr=1e-2)
    for i in range(5):
        _step(single, ref, i)
    state = copy.deepcopy(single.state_dict())  # as read back from a file: no shared tensors
    with torch.no_grad():
        for a, b in zip(ref, ours, strict=True):
            b.copy_(a)
    optim.FUSED = True
    fused = optim.adam(ours, lr=1e-2)
    optim.load_state(fused, state)
    assert fused.param_groups[0]["fused"]  # torch's load_state_dict alone gives the saved None
    for i in range(5, 10):
        _step(single, ref, i)
        _step(fused, ours, i)
    for a, b in zip(ref, ours, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6)
