"""Transmittance along TX rays through the density field (paper §4.4).

For samples ``x_0, x_1, ...`` on one ray, ordered by radius, at distances ``l_i`` from the TX,

    T_i = prod_{j<i} exp(-rho(x_j) |l_{j+1} - l_j|),

i.e. the density at a sample fills the gap up to the next sample. The return leg ``T(x, o_R)``
is approximated by the transmit leg, ``T(x, o_R) ≈ T(o_T, x)`` (exact when TX and RX coincide;
the public code of the paper does the same by doubling the occlusion scale), so the two-way
factor is ``T_i^2 = exp(-2 sum_{j<i} rho_j dl_j)``.
"""

from __future__ import annotations

import torch
from torch import Tensor


def optical_depth(density: Tensor, dist: Tensor) -> Tensor:
    """Exclusive cumulative optical depth ``tau_i = sum_{j<i} rho_j |l_{j+1} - l_j|``.

    Args:
        density: (..., K, M) rho >= 0 at the samples, 1/m (0 at invalid samples).
        dist: (..., K, M) distances along the rays, m, non-decreasing in K for valid samples.
    Returns:
        (..., K, M) tau, dimensionless; ``tau_0 = 0``.
    """
    seg = (dist[..., 1:, :] - dist[..., :-1, :]).abs()
    step = density[..., :-1, :] * seg
    tau = torch.cumsum(step, dim=-2)
    return torch.cat([torch.zeros_like(density[..., :1, :]), tau], dim=-2)


def transmittance(density: Tensor, dist: Tensor, two_way: bool = True) -> Tensor:
    """``T_i`` (one way) or ``T_i^2`` (two way): exponential of the exclusive cumulative sum.

    Shapes as :func:`optical_depth`; returns (..., K, M) in (0, 1].
    """
    tau = optical_depth(density, dist)
    return torch.exp(-(2.0 if two_way else 1.0) * tau)


def transmittance_cumprod(density: Tensor, dist: Tensor, two_way: bool = True) -> Tensor:
    """The paper's product form (exclusive cumulative product of ``exp(-rho dl)``); the eager
    reference for :func:`transmittance`, same shapes and result."""
    seg = (dist[..., 1:, :] - dist[..., :-1, :]).abs()
    att = torch.exp(-density[..., :-1, :] * seg)
    ones = torch.ones_like(density[..., :1, :])
    t = torch.cumprod(torch.cat([ones, att], dim=-2), dim=-2)
    return t * t if two_way else t
