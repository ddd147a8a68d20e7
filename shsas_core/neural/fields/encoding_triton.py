"""The hash encoding as Triton kernels: forward (features and spatial Jacobian) and backward
(table gradient by atomic adds, gradient with respect to the points).

Same maths as :func:`.encoding.encode_fused` (the same float cells, rows and nested lerps), but
one GPU program owns a block of points on one level and keeps the 8 corner values of each point
in registers: no ``(F, 8, P, Lv)`` intermediate is written, which is where the PyTorch fused ops
spend their time. The backward scatters each corner's gradient into the table with
``tl.atomic_add`` (on CUDA the sum order, and so the last bits, vary from run to run, as with
``index_add``).

Double backward (``create_graph=True`` through the encoding's backward) is not written as a
kernel: the field needs none (its normals come from the forward's analytic Jacobian, and
training is a first-order backward), so the rare caller that asks for it (a gradgradcheck, the
``reference`` field's autograd normals never come here) gets the PyTorch fused ops recomputed
inside the backward, differentiable to any order.

Where it runs: CUDA tensors, when Triton imports (CUDA builds of torch ship it; the CPU wheel
the project pins does not). On CPU tensors it runs only under Triton's interpreter
(``TRITON_INTERPRET=1``), which is how the tests check it without a GPU. The kernels are built
on first use, not at import, so the interpreter setting is read when they are made, not when
this module is imported. Float32 and float64 tables; other dtypes are refused here (the field's
``native`` backend then keeps the PyTorch ops).
"""

from __future__ import annotations

import os
from typing import Any

import torch

from shsas_core.common.errors import ShsasError
from shsas_core.neural.fields.encoding import (
    FusedLayout,
    _gather,
    _lerp_forward,
    _to_point_major,
    fused_rows,
)

try:  # the CPU wheel of torch has no Triton
    import triton
    import triton.language as tl
except ImportError:  # pragma: no cover - exercised on installs without Triton
    triton = None

#: Points per program (one per thread at 4 warps).
BLOCK_POINTS = 128
#: Table dtypes the kernels take (atomic adds exist for both on CUDA).
DTYPES = (torch.float32, torch.float64)


def available() -> bool:
    """True when Triton imports."""
    return triton is not None


def interpreting() -> bool:
    """Whether Triton's interpreter is on (``TRITON_INTERPRET=1``): kernels then run on CPU tensors."""
    if triton is None:
        return False
    return bool(triton.knobs.runtime.interpret)


def unsupported(u: torch.Tensor, table: torch.Tensor) -> str | None:
    """Why the kernels cannot take these tensors (a sentence), or None when they can."""
    if triton is None:
        return "Triton is not installed (CUDA builds of torch ship it; pip install triton)"
    if u.device != table.device:
        return f"points on {u.device} and table on {table.device}"
    if table.device.type == "cpu" and not interpreting():
        return "CPU tensors need Triton's interpreter (TRITON_INTERPRET=1); the kernels are for CUDA"
    if table.device.type not in ("cpu", "cuda"):
        return f"device {table.device} is neither CUDA nor the CPU interpreter"
    if table.dtype not in DTYPES:
        return f"table dtype {table.dtype} (the kernels take float32 and float64)"
    if u.dtype != table.dtype:
        return f"points in {u.dtype} and table in {table.dtype} (the kernels take one dtype)"
    return None


def usable(u: torch.Tensor, table: torch.Tensor) -> bool:
    """Whether the field's ``native`` backend takes the kernels: CUDA tensors the kernels
    support, and neither ``SHSAS_NATIVE=0`` nor ``SHSAS_TRITON=0`` set."""
    off = ("0", "false", "no")
    if os.environ.get("SHSAS_NATIVE", "1") in off or os.environ.get("SHSAS_TRITON", "1") in off:
        return False
    return u.device.type == "cuda" and unsupported(u, table) is None


def _hash_kernel(u_ptr, tab_ptr, res_ptr, mult_ptr, off_ptr, out_ptr, jac_ptr, gtab_ptr, gu_ptr,
                 P, n_dense, mask,
                 F: tl.constexpr, NL: tl.constexpr, JAC: tl.constexpr, BACKWARD: tl.constexpr,
                 NEED_TABLE: tl.constexpr, NEED_U: tl.constexpr, BLOCK: tl.constexpr):
    """One program: BLOCK points on one level.

    Forward: writes the features out (P, NL*F) and, when JAC, the Jacobian jac (3, P, NL*F).
    Backward: reads their gradients from out_ptr and jac_ptr; when NEED_TABLE adds each
    corner's gradient into gtab (N, F); when NEED_U writes this level's part of the points'
    gradient into gu (NL, 3, P).

    With per-axis weights W = (1 - f, f) and slopes S = res (-1, +1), the corner gradient is
    W W W g + S W W g_x + W S W g_y + W W S g_z. The points' gradient is g jac_a plus, from the
    Jacobian's own gradient, res^2 (g_b H_ab + g_c H_ac), H the mixed second differences of the
    cell (a trilinear cell has no pure second derivative).
    """
    lvl = tl.program_id(1)
    # int64: offs * Lv * F * 3 passes 2^31 at tens of millions of points
    offs = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    inside = offs < P
    res = tl.load(res_ptr + lvl)
    m0 = tl.load(mult_ptr + lvl * 3)
    m1 = tl.load(mult_ptr + lvl * 3 + 1)
    m2 = tl.load(mult_ptr + lvl * 3 + 2)
    base = tl.load(off_ptr + lvl)
    dense = lvl < n_dense
    # cells exactly as encoding._rows_frac; NaN reads the origin's cell (never outside the table)
    ux = tl.load(u_ptr + offs * 3, mask=inside, other=0.0)
    uy = tl.load(u_ptr + offs * 3 + 1, mask=inside, other=0.0)
    uz = tl.load(u_ptr + offs * 3 + 2, mask=inside, other=0.0)
    ux = tl.minimum(tl.maximum(tl.where(ux == ux, ux, 0.0), 0.0), 1.0)
    uy = tl.minimum(tl.maximum(tl.where(uy == uy, uy, 0.0), 0.0), 1.0)
    uz = tl.minimum(tl.maximum(tl.where(uz == uz, uz, 0.0), 0.0), 1.0)
    xs = ux * res
    ys = uy * res
    zs = uz * res
    lx = tl.maximum(tl.minimum(tl.floor(xs), res - 1), 0.0)
    ly = tl.maximum(tl.minimum(tl.floor(ys), res - 1), 0.0)
    lz = tl.maximum(tl.minimum(tl.floor(zs), res - 1), 0.0)
    fx = xs - lx
    fy = ys - ly
    fz = zs - lz
    ix = lx.to(tl.int64)
    iy = ly.to(tl.int64)
    iz = lz.to(tl.int64)
    # per-axis terms of the 8 corners' rows r{z}{y}{x}: a sum (dense) or the masked xor (hashed)
    ax0 = ix * m0
    ax1 = (ix + 1) * m0
    ay0 = iy * m1
    ay1 = (iy + 1) * m1
    az0 = iz * m2
    az1 = (iz + 1) * m2
    r000 = tl.where(dense, ax0 + ay0 + az0, (ax0 ^ ay0 ^ az0) & mask) + base
    r001 = tl.where(dense, ax1 + ay0 + az0, (ax1 ^ ay0 ^ az0) & mask) + base
    r010 = tl.where(dense, ax0 + ay1 + az0, (ax0 ^ ay1 ^ az0) & mask) + base
    r011 = tl.where(dense, ax1 + ay1 + az0, (ax1 ^ ay1 ^ az0) & mask) + base
    r100 = tl.where(dense, ax0 + ay0 + az1, (ax0 ^ ay0 ^ az1) & mask) + base
    r101 = tl.where(dense, ax1 + ay0 + az1, (ax1 ^ ay0 ^ az1) & mask) + base
    r110 = tl.where(dense, ax0 + ay1 + az1, (ax0 ^ ay1 ^ az1) & mask) + base
    r111 = tl.where(dense, ax1 + ay1 + az1, (ax1 ^ ay1 ^ az1) & mask) + base
    width = NL * F
    plane = P * width
    # not tl.zeros: triton.language's own jitted helpers are interpreted only when
    # TRITON_INTERPRET was set before Triton was imported (fx is finite: NaN was mapped to 0)
    gux = fx * 0.0
    guy = fx * 0.0
    guz = fx * 0.0
    for f in tl.static_range(F):
        col = offs * width + lvl * F + f
        if (not BACKWARD) or NEED_U:
            # corner values v{z}{y}{x}, then nested lerps in x, y, z (as encoding._lerp_forward)
            v000 = tl.load(tab_ptr + r000 * F + f, mask=inside, other=0.0)
            v001 = tl.load(tab_ptr + r001 * F + f, mask=inside, other=0.0)
            v010 = tl.load(tab_ptr + r010 * F + f, mask=inside, other=0.0)
            v011 = tl.load(tab_ptr + r011 * F + f, mask=inside, other=0.0)
            v100 = tl.load(tab_ptr + r100 * F + f, mask=inside, other=0.0)
            v101 = tl.load(tab_ptr + r101 * F + f, mask=inside, other=0.0)
            v110 = tl.load(tab_ptr + r110 * F + f, mask=inside, other=0.0)
            v111 = tl.load(tab_ptr + r111 * F + f, mask=inside, other=0.0)
            d00 = v001 - v000  # x-differences d{z}{y}
            d01 = v011 - v010
            d10 = v101 - v100
            d11 = v111 - v110
            a00 = v000 + fx * d00  # lerped in x: a{z}{y}
            a01 = v010 + fx * d01
            a10 = v100 + fx * d10
            a11 = v110 + fx * d11
            e0 = a01 - a00  # y-differences e{z}
            e1 = a11 - a10
            b0 = a00 + fy * e0
            b1 = a10 + fy * e1
            c0 = d00 + fy * (d01 - d00)
            c1 = d10 + fy * (d11 - d10)
            # d out / d f_a (the Jacobian over res)
            jx = c0 + fz * (c1 - c0)
            jy = e0 + fz * (e1 - e0)
            jz = b1 - b0
        if not BACKWARD:
            tl.store(out_ptr + col, b0 + fz * jz, mask=inside)
            if JAC:
                tl.store(jac_ptr + col, jx * res, mask=inside)
                tl.store(jac_ptr + plane + col, jy * res, mask=inside)
                tl.store(jac_ptr + 2 * plane + col, jz * res, mask=inside)
        else:
            g = tl.load(out_ptr + col, mask=inside, other=0.0)
            if JAC:
                gx = tl.load(jac_ptr + col, mask=inside, other=0.0) * res
                gy = tl.load(jac_ptr + plane + col, mask=inside, other=0.0) * res
                gz = tl.load(jac_ptr + 2 * plane + col, mask=inside, other=0.0) * res
            if NEED_TABLE:
                # split along x: lower (1 - fx) g - gx, upper fx g + gx; then along y and z
                hx1 = fx * g
                hx0 = g - hx1
                if JAC:
                    hx1 += gx
                    hx0 -= gx
                    py1 = fx * gy  # the y- and z-slope terms, split along x
                    py0 = gy - py1
                    pz1 = fx * gz
                    pz0 = gz - pz1
                for cy in tl.static_range(2):
                    if cy == 1:
                        wy = fy
                        sy = 1.0
                    else:
                        wy = 1.0 - fy
                        sy = -1.0
                    qx0 = wy * hx0
                    qx1 = wy * hx1
                    if JAC:
                        qx0 += sy * py0
                        qx1 += sy * py1
                        tx0 = wy * pz0  # z-slope, split along x and y
                        tx1 = wy * pz1
                    for cz in tl.static_range(2):
                        if cz == 1:
                            wz = fz
                            sz = 1.0
                        else:
                            wz = 1.0 - fz
                            sz = -1.0
                        d0 = wz * qx0
                        d1 = wz * qx1
                        if JAC:
                            d0 += sz * tx0
                            d1 += sz * tx1
                        if cz == 0:
                            if cy == 0:
                                ra = r000
                                rb = r001
                            else:
                                ra = r010
                                rb = r011
                        else:
                            if cy == 0:
                                ra = r100
                                rb = r101
                            else:
                                ra = r110
                                rb = r111
                        tl.atomic_add(gtab_ptr + ra * F + f, d0, mask=inside)
                        tl.atomic_add(gtab_ptr + rb * F + f, d1, mask=inside)
            if NEED_U:
                gux += g * jx * res
                guy += g * jy * res
                guz += g * jz * res
                if JAC:
                    hxy = (d01 - d00) + fz * ((d11 - d10) - (d01 - d00))  # Σ Sx Sy Wz v
                    hxz = c1 - c0  # Σ Sx Wy Sz v
                    hyz = e1 - e0  # Σ Wx Sy Sz v
                    # gx, gy, gz carry one res; d f / d u carries the other
                    gux += (gy * hxy + gz * hxz) * res
                    guy += (gx * hxy + gz * hyz) * res
                    guz += (gx * hxz + gy * hyz) * res
    if BACKWARD and NEED_U:
        row = lvl * 3 * P + offs
        tl.store(gu_ptr + row, gux, mask=inside)
        tl.store(gu_ptr + P + row, guy, mask=inside)
        tl.store(gu_ptr + 2 * P + row, guz, mask=inside)


_KERNELS: dict[bool, Any] = {}


def _kernel() -> Any:
    """The jitted kernel for the current interpreter setting, made once for each.

    ``triton.jit`` decides at decoration time whether a kernel is interpreted, so decorating
    here (not at import) lets the setting be changed after this module is imported.
    """
    if triton is None:
        raise ShsasError("the Triton hash encoding needs Triton (a CUDA build of torch, or pip install triton)")
    key = interpreting()
    if key not in _KERNELS:
        _KERNELS[key] = triton.jit(_hash_kernel)
    return _KERNELS[key]


def _launch(u, table, res, mult, offsets, n_dense, mask, a, b, gtab, gu, jac, backward, need_table, need_u):
    p, feat, nl = u.shape[0], table.shape[1], res.shape[0]
    if p == 0:
        return
    grid = (triton.cdiv(p, BLOCK_POINTS), nl)
    _kernel()[grid](u, table, res, mult, offsets, a, b, gtab, gu, p, n_dense, mask, F=feat, NL=nl, JAC=jac,
                    BACKWARD=backward, NEED_TABLE=need_table, NEED_U=need_u, BLOCK=BLOCK_POINTS, num_warps=4)


def forward(u: torch.Tensor, table: torch.Tensor, res: torch.Tensor, mult: torch.Tensor, offsets: torch.Tensor,
            n_dense: int, mask: int, with_jacobian: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Features (P, Lv*F) and, with ``with_jacobian``, the Jacobian (3, P, Lv*F) (else empty).

    u (P, 3) and table (N, F) in one dtype on one device; res (Lv,) in that dtype; mult (Lv, 3)
    and offsets (Lv,) int64; ``n_dense`` leading dense levels; ``mask`` = table size - 1.
    """
    u = u.detach().contiguous()
    table = table.detach().contiguous()
    p, feat, nl = u.shape[0], table.shape[1], res.shape[0]
    out = torch.empty((p, nl * feat), dtype=table.dtype, device=table.device)
    jac = torch.empty((3, p, nl * feat) if with_jacobian else (0,), dtype=table.dtype, device=table.device)
    _launch(u, table, res, mult, offsets, n_dense, mask, out, jac if with_jacobian else out, out, out,
            with_jacobian, False, False, False)
    return out, jac


def backward(u: torch.Tensor, table: torch.Tensor, g_out: torch.Tensor, g_jac: torch.Tensor | None,
             res: torch.Tensor, mult: torch.Tensor, offsets: torch.Tensor, n_dense: int, mask: int,
             need_table: bool, need_u: bool) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """Table gradient (N, F) and points' gradient (P, 3) (each None when not asked for) from the
    gradients of the features (P, Lv*F) and of the Jacobian (3, P, Lv*F) (None: no Jacobian)."""
    u = u.detach().contiguous()
    table = table.detach().contiguous()
    p, nl = u.shape[0], res.shape[0]
    g_out = g_out.to(table.dtype).contiguous()
    gj = g_jac.to(table.dtype).contiguous() if g_jac is not None else g_out
    g_tab = torch.zeros_like(table) if need_table else None
    # one slice per level, summed below: no atomics on the points, so their gradient is exact
    g_u = torch.empty((nl, 3, p), dtype=table.dtype, device=table.device) if need_u else None
    if need_table or need_u:
        _launch(u, table, res, mult, offsets, n_dense, mask, g_out, gj, g_tab if need_table else g_out,
                g_u if need_u else g_out, g_jac is not None, True, need_table, need_u)
    return g_tab, (g_u.sum(0).t() if g_u is not None else None)


def _torch_forward(u: torch.Tensor, table: torch.Tensor, fl: FusedLayout,
                   with_jacobian: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The same features and Jacobian from the PyTorch fused ops (differentiable to any order)."""
    rows, frac = fused_rows(u, fl)
    out, jac = _lerp_forward(_gather(table, rows), frac.to(table.dtype), fl.res.to(table.dtype), with_jacobian)
    return _to_point_major(out, jac)


class _TritonEncode(torch.autograd.Function):
    """Features and Jacobian by the forward kernel; table and points gradients by the backward
    kernel. A backward under ``create_graph`` recomputes the PyTorch fused ops instead (module doc)."""

    @staticmethod
    def forward(ctx, table, u, fl, with_jacobian):
        ctx.fl, ctx.with_jacobian = fl, with_jacobian
        ctx.set_materialize_grads(False)
        ctx.save_for_backward(table, u)
        res = fl.res.to(table.dtype)
        return forward(u, table, res, fl.mult, fl.offsets.long(), fl.n_dense, fl.mask, with_jacobian)

    @staticmethod
    def backward(ctx, g_out, g_jac):
        table, u = ctx.saved_tensors
        fl, with_jacobian = ctx.fl, ctx.with_jacobian
        need_table, need_u = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if g_out is None:
            g_out = torch.zeros((u.shape[0], table.shape[1] * fl.res.shape[0]), dtype=table.dtype,
                                device=table.device)
        if not with_jacobian:
            g_jac = None
        if torch.is_grad_enabled():  # create_graph: a backward that is itself differentiable
            inputs = [t for t, need in ((table, need_table), (u, need_u)) if need]
            with torch.enable_grad():
                out, jac = _torch_forward(u, table, fl, with_jacobian)
                outs, grads = [out], [g_out]
                if g_jac is not None:
                    outs.append(jac)
                    grads.append(g_jac)
                got = list(torch.autograd.grad(outs, inputs, grads, create_graph=True, allow_unused=True))
            g_tab = got.pop(0) if need_table else None
            g_u = got.pop(0) if need_u else None
            return g_tab, g_u, None, None
        g_tab, g_u = backward(u, table, g_out, g_jac, fl.res.to(table.dtype), fl.mult, fl.offsets.long(),
                              fl.n_dense, fl.mask, need_table, need_u)
        return g_tab, g_u, None, None


def encode_triton(u: torch.Tensor, table: torch.Tensor, fl: FusedLayout,
                  with_jacobian: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
    """:func:`.encoding.encode_fused` by the Triton kernels (same arguments and results).

    Differentiable in ``table`` and ``u`` (first order by the kernels, higher orders by the
    PyTorch fused ops, module doc). Raises :class:`ShsasError` when the kernels cannot take the
    tensors (:func:`unsupported` says why).
    """
    why = unsupported(u, table)
    if why is not None:
        raise ShsasError(f"hash encoding backend 'triton': {why}")
    u = u.clamp(0.0, 1.0)
    out, jac = _TritonEncode.apply(table, u, fl, with_jacobian)
    return out, (jac if with_jacobian else None)
