"""The backprojection block kernel as one Triton kernel, for CUDA devices.

Same contract as :func:`shsas_core.imaging.backprojection._bp_block` (same arguments, same sums), but
one GPU program owns a block of voxels and loops over the chunk's pings with its running sums in
registers: no (voxels x pings) tensor is ever formed, and each ping's signal samples are read
through the cache by neighbouring voxels. ``torch.compile`` of the plain kernel reached 10-19 G
voxel-pings/s on an H100 (docs/notebook/2026-11-lab-notebook.md); this loop is what it could not find.

Triton ships with CUDA builds of PyTorch, not with the CPU wheel the project pins, so this module
is imported only for CUDA devices (:func:`available` tells whether it can be).
"""

from __future__ import annotations

import torch
from torch import Tensor

try:  # the CPU wheel of torch has no Triton
    import triton
    import triton.language as tl
    from triton.language.extra import libdevice
except ImportError:  # pragma: no cover - exercised on CPU-only installs
    triton = None

#: Voxels per GPU program (one per thread at 4 warps).
BLOCK_VOXELS = 128


def available() -> bool:
    """True when Triton imports (CUDA builds of torch)."""
    return triton is not None


if triton is not None:

    @triton.jit
    def _bp_kernel(px, py, pz, tx, rx, a, sig, k_ptr, pk_ptr, txd, rxd, out_re, out_im,
                   V, N, T1,
                   NEAREST: tl.constexpr, PHASE: tl.constexpr, BEAMS: tl.constexpr,
                   BLOCK: tl.constexpr):
        offs = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
        inside = offs < V
        x = tl.load(px + offs, mask=inside, other=0.0)
        y = tl.load(py + offs, mask=inside, other=0.0)
        z = tl.load(pz + offs, mask=inside, other=0.0)
        k = tl.load(k_ptr)
        pk = tl.load(pk_ptr)
        last = (T1 - 2).to(tl.float32)  # the last sample with a right neighbour
        acc_re = tl.zeros([BLOCK], dtype=tl.float32)
        acc_im = tl.zeros([BLOCK], dtype=tl.float32)
        for n in range(N):
            ex = x - tl.load(tx + n)
            ey = y - tl.load(tx + N + n)
            ez = z - tl.load(tx + 2 * N + n)
            fx = x - tl.load(rx + n)
            fy = y - tl.load(rx + N + n)
            fz = z - tl.load(rx + 2 * N + n)
            dt = tl.sqrt_rn(ex * ex + ey * ey + ez * ez)
            dr = tl.sqrt_rn(fx * fx + fy * fy + fz * fz)
            d = dt + dr
            idx = d * k - tl.load(a + n)
            valid = inside & (idx >= 0.0) & (idx <= last)
            if BEAMS:
                ct = ex * tl.load(txd + n) + ey * tl.load(txd + N + n) + ez * tl.load(txd + 2 * N + n)
                cr = fx * tl.load(rxd + n) + fy * tl.load(rxd + N + n) + fz * tl.load(rxd + 2 * N + n)
                valid = valid & (ct >= tl.load(txd + 3 * N + n) * dt) & (cr >= tl.load(rxd + 3 * N + n) * dr)
            fl = tl.minimum(tl.maximum(tl.floor(idx), 0.0), last)
            base = (fl.to(tl.int32) + n * T1) * 2
            re = tl.load(sig + base, mask=valid, other=0.0)
            im = tl.load(sig + base + 1, mask=valid, other=0.0)
            if not NEAREST:
                w = idx - fl
                re = re + w * (tl.load(sig + base + 2, mask=valid, other=0.0) - re)
                im = im + w * (tl.load(sig + base + 3, mask=valid, other=0.0) - im)
            if PHASE:
                # libdevice's sin/cos reduce the ~10^2-10^3 rad argument exactly; the fast
                # approximate instructions lose the phase there
                ph = d * pk
                c = libdevice.cos(ph)
                s = libdevice.sin(ph)
                re, im = re * c - im * s, re * s + im * c
            acc_re += re
            acc_im += im
        tl.store(out_re + offs, acc_re, mask=inside)
        tl.store(out_im + offs, acc_im, mask=inside)


def bp_block(px: Tensor, py: Tensor, pz: Tensor, tx: Tensor, rx: Tensor, a: Tensor, sig: Tensor,
             k: Tensor, phase_k: Tensor, txd: Tensor, rxd: Tensor, nearest: bool, with_phase: bool,
             with_beams: bool) -> tuple[Tensor, Tensor]:
    """Sum over one chunk of pings for one block of voxels, on a CUDA device.

    Arguments and result as :func:`shsas_core.imaging.backprojection._bp_block` (all float32 CUDA
    tensors, contiguous): (V,) coordinates, (3, N) sensors, (N,) time-zero indices, the flat
    re/im-interleaved (N·(T+1)·2,) signals, 0-d ``k`` and ``phase_k``, (4, N) beam rows.
    """
    if triton is None:
        raise RuntimeError("the Triton backprojection kernel needs Triton (a CUDA build of torch)")
    v, n = px.shape[0], a.shape[0]
    t1 = sig.shape[0] // (2 * n)
    out_re = torch.empty(v, dtype=torch.float32, device=px.device)
    out_im = torch.empty_like(out_re)
    grid = (triton.cdiv(v, BLOCK_VOXELS),)
    _bp_kernel[grid](px, py, pz, tx, rx, a, sig, k, phase_k, txd, rxd, out_re, out_im, v, n, t1,
                     NEAREST=nearest, PHASE=with_phase, BEAMS=with_beams, BLOCK=BLOCK_VOXELS,
                     num_warps=4)
    return out_re, out_im
