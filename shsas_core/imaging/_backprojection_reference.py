"""Plain PyTorch backprojection: the straightforward way (and the public baseline's approach).

For each chunk of pings: broadcast (voxels x pings) distances, turn them into fractional sample
indices, gather the two neighbouring samples, interpolate linearly and sum over pings. It
materialises several (V, N) temporaries, so it is slow and memory-hungry, but it is short
enough to check by eye. It is the correctness oracle of the tests and the speed baseline of
``benchmarks/bench_backprojection.py``. Same semantics as :func:`shsas_core.imaging.backprojection.backproject`
with ``interpolation="linear"`` and no beams.
"""

from __future__ import annotations

import math

import numpy as np
import torch


def reference_backproject(
    signals: np.ndarray,
    tx: np.ndarray,
    rx: np.ndarray,
    t0: np.ndarray,
    fs: float,
    c: float,
    points: np.ndarray,
    *,
    carrier_hz: float | None = None,
    ping_chunk: int = 64,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
) -> np.ndarray:
    """Backproject (N, T) complex signals onto (V, 3) points; returns (V,) complex128.

    ``dtype`` float64 makes it an accurate oracle; float32 is the baseline's precision.
    """
    cdt = torch.complex128 if dtype == torch.float64 else torch.complex64
    pts = torch.as_tensor(points, dtype=dtype, device=device)
    sig = torch.as_tensor(signals).to(device=device, dtype=cdt)
    n, t = sig.shape
    out = torch.zeros(len(pts), dtype=cdt, device=device)
    for a in range(0, n, ping_chunk):
        b = min(a + ping_chunk, n)
        txc = torch.as_tensor(tx[a:b], dtype=dtype, device=device)
        rxc = torch.as_tensor(rx[a:b], dtype=dtype, device=device)
        t0c = torch.as_tensor(t0[a:b], dtype=dtype, device=device)
        d = torch.linalg.norm(pts[:, None] - txc[None], dim=-1) + torch.linalg.norm(pts[:, None] - rxc[None], dim=-1)
        idx = (d / c - t0c[None]) * fs
        valid = (idx >= 0) & (idx <= t - 1)
        i0 = torch.floor(idx).clamp(0, t - 2).long()
        w = (idx - i0).clamp(0, 1)
        rows = sig[a:b]
        g0 = torch.gather(rows[None].expand(len(pts), -1, -1), 2, i0[..., None])[..., 0]
        g1 = torch.gather(rows[None].expand(len(pts), -1, -1), 2, (i0 + 1)[..., None])[..., 0]
        val = g0 * (1 - w) + g1 * w
        if carrier_hz is not None:
            val = val * torch.exp(1j * (2 * math.pi * carrier_hz / c) * d)
        out += torch.where(valid, val, torch.zeros((), dtype=cdt, device=device)).sum(1)
    return out.cpu().numpy().astype(np.complex128)
