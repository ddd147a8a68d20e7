"""The Adam optimiser of every fit in the project (neural field, warm start, neural deconvolution).

Torch's default Adam on CPU tensors is the single-tensor implementation: a Python loop over the
parameters and several elementwise passes over each. A field's hash tables are millions of
floats, so on CPU that loop is a sizeable share of a training step; the fused implementation
updates each tensor in one pass (``benchmarks/bench_optim.py`` prints both, for one step and
for a whole job). Same update rule, other rounding: volumes are not byte-equal across the two.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import torch

#: Fused Adam for every fit. Off: torch's default implementation for the device (the
#: single-tensor loop on CPU), which the pipeline identity test's recorded digests were made with.
FUSED: bool = True


def adam(params: Iterable[torch.Tensor], lr: float) -> torch.optim.Adam:
    """Adam at learning rate ``lr`` over ``params`` (float tensors on one device type)."""
    return torch.optim.Adam(params, lr=lr, fused=True) if FUSED else torch.optim.Adam(params, lr=lr)


def load_state(opt: torch.optim.Adam, state: dict[str, Any]) -> None:
    """Load ``state`` (saved by either Adam implementation) into ``opt``, which keeps its own.

    Torch's ``load_state_dict`` takes the saved groups' ``fused``/``foreach`` flags, so a
    checkpoint written under the single-tensor Adam would resume in it; and the fused kernels
    want each step count as a float32 tensor on its parameter's device.
    """
    opt.load_state_dict(state)
    for group in opt.param_groups:
        group["fused"], group["foreach"] = opt.defaults["fused"], opt.defaults["foreach"]
        for p in group["params"]:
            st = opt.state.get(p, {})
            if group["fused"] and "step" in st:
                st["step"] = torch.as_tensor(st["step"], dtype=torch.float32, device=p.device)
