"""Multi-resolution hash encoding (Müller et al. 2022, "Instant-NGP") in pure PyTorch.

Input: points ``u`` (P, 3) already normalised to the unit cube [0, 1]^3 (the field does the
scene-box normalisation). Output: features (P, n_levels * n_features), level-major
(level 0's features first).

Level ``l`` has resolution ``N_l = floor(N_min * b^l)`` with ``b = exp((ln N_max - ln N_min) /
(n_levels - 1))`` (Instant-NGP eq. 2). A point is scaled by ``N_l``; the 8 surrounding grid
vertices (integer coordinates 0..N_l) are trilinearly interpolated. Vertex features live in
one flat parameter table; level ``l`` owns rows ``offsets[l] .. offsets[l] + size_l``:

* dense levels, where ``(N_l + 1)^3 <= 2^log2_table_size``: row ``i + j (N_l+1) + k (N_l+1)^2``,
  collision free;
* hashed levels: row ``(i * 1 xor j * 2654435761 xor k * 805459861) mod 2^log2_table_size``
  (the Instant-NGP spatial hash, uint32 arithmetic).

Two implementations of the same maths:

* :func:`encode_reference`: the plain eager version, a Python loop over levels and corners; the
  reference every faster path is tested against.
* :func:`encode_fused`: all levels and corners in one batched gather (``index_select`` on a
  complex view of the table, whose backward is a matching ``index_add``), no Python loop over
  levels, nested lerps instead of 8 corner weights. Optionally also returns the analytic spatial
  Jacobian of the features (as tangents (3, P, D)) from the same gathered corner values; the
  field uses it to get normals by forward-mode differentiation in the same pass.

Both are built from differentiable torch ops only, so they are differentiable to any order with
respect to the table and the input (double backward for create_graph normals works).
"""

from __future__ import annotations

import math

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..errors import ShsasError

# Instant-NGP spatial-hash primes (the first is 1: no multiply on x).
PRIMES = (1, 2654435761, 805459861)

# Corners of a cell are numbered c = 4*cz + 2*cy + cx (cx, cy, cz in {0, 1}) in both paths.


class HashEncodingConfig(BaseModel):
    """Shape of the multi-resolution hash grid.

    The default is the CPU preset (trains in minutes on 2 cores); :data:`PAPER_GPU_ENCODING` is
    the paper's GPU setting.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_levels: int = Field(12, ge=1, le=32, description="number of resolution levels")
    n_features: int = Field(2, ge=1, le=8, description="features per level")
    log2_table_size: int = Field(15, ge=4, le=24, description="log2 of the table rows per level")
    base_resolution: int = Field(16, ge=2, le=1 << 16, description="coarsest grid resolution N_min")
    finest_resolution: int = Field(512, ge=2, le=1 << 16, description="finest grid resolution N_max")
    init_scale: float = Field(1e-4, gt=0, le=1.0, description="table init: uniform(-s, s)")

    @model_validator(mode="after")
    def _ordered(self) -> HashEncodingConfig:
        if self.finest_resolution < self.base_resolution:
            raise ValueError(
                f"finest_resolution {self.finest_resolution} must be >= base_resolution {self.base_resolution}"
            )
        return self

    @property
    def output_dim(self) -> int:
        return self.n_levels * self.n_features

    def resolutions(self) -> list[int]:
        """Grid resolution N_l of each level (integers, coarse to fine)."""
        if self.n_levels == 1:
            return [self.base_resolution]
        b = math.exp((math.log(self.finest_resolution) - math.log(self.base_resolution)) / (self.n_levels - 1))
        # the tiny epsilon keeps exact powers (16 * 2^8 = 4096) from flooring to 4095
        return [math.floor(self.base_resolution * b**lvl + 1e-6) for lvl in range(self.n_levels)]


#: Paper setting (GPU): 16 levels x 2 features, N_min 16, N_max 4096, 2^19 rows per level.
PAPER_GPU_ENCODING = HashEncodingConfig(
    n_levels=16, n_features=2, log2_table_size=19, base_resolution=16, finest_resolution=4096
)
#: CPU default: 12 levels x 2 features, N_min 16, N_max 512, 2^15 rows per level (~0.7 M params).
CPU_ENCODING = HashEncodingConfig()

PRESETS: dict[str, HashEncodingConfig] = {"paper_gpu": PAPER_GPU_ENCODING, "cpu": CPU_ENCODING}


def encoding_preset(name: str) -> HashEncodingConfig:
    """The named preset (``paper_gpu`` or ``cpu``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ShsasError(f"encoding preset: unknown name '{name}' (use one of {sorted(PRESETS)})") from None


class LevelLayout:
    """Per-level integers derived from a config: resolution, dense flag, row offset and count."""

    def __init__(self, cfg: HashEncodingConfig):
        self.table_size = 1 << cfg.log2_table_size
        self.resolutions = cfg.resolutions()
        self.dense: list[bool] = []
        self.sizes: list[int] = []
        self.offsets: list[int] = []
        off = 0
        for n in self.resolutions:
            verts = (n + 1) ** 3
            dense = verts <= self.table_size
            size = verts if dense else self.table_size
            self.dense.append(dense)
            self.sizes.append(size)
            self.offsets.append(off)
            off += size
        self.total_rows = off


def _cell(u: torch.Tensor, res: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower cell corner and fractional position. u (..., 3) in [0,1]; res broadcastable.

    Returns (i0 int64, frac float). The corner is clamped to res - 1 so u = 1 interpolates the
    last cell at frac = 1 instead of reading vertex res + 1.
    """
    xs = u * res
    i0 = torch.minimum(torch.floor(xs), res - 1).clamp_min(0)
    # frac carries the gradient: d frac / d u = res (floor has zero derivative)
    return i0.long(), xs - i0


def _level_rows(i: torch.Tensor, j: torch.Tensor, k: torch.Tensor, n: int, dense: bool, table_size: int) -> torch.Tensor:
    """Table row of integer vertices (i, j, k) on one level (int64, any shape)."""
    if dense:
        return i + j * (n + 1) + k * (n + 1) ** 2
    return (i * PRIMES[0] ^ j * PRIMES[1] ^ k * PRIMES[2]) & (table_size - 1)


def encode_reference(u: torch.Tensor, table: torch.Tensor, layout: LevelLayout) -> torch.Tensor:
    """Eager reference encoding: Python loops over levels and over the 8 corners.

    Args:
        u: (P, 3) points in [0, 1]^3 (clamped here), float.
        table: (layout.total_rows, F) vertex features.
        layout: level layout of the config that built ``table``.

    Returns:
        (P, n_levels * F) features, level-major.
    """
    u = u.clamp(0.0, 1.0)
    outs = []
    for lvl, n in enumerate(layout.resolutions):
        i0, f = _cell(u, torch.tensor(float(n), dtype=u.dtype, device=u.device))
        tab = table[layout.offsets[lvl] : layout.offsets[lvl] + layout.sizes[lvl]]
        acc = torch.zeros(u.shape[0], table.shape[1], dtype=table.dtype, device=u.device)
        for c in range(8):
            cx, cy, cz = c & 1, (c >> 1) & 1, (c >> 2) & 1
            rows = _level_rows(i0[:, 0] + cx, i0[:, 1] + cy, i0[:, 2] + cz, n, layout.dense[lvl], layout.table_size)
            w = (
                (f[:, 0] if cx else 1 - f[:, 0])
                * (f[:, 1] if cy else 1 - f[:, 1])
                * (f[:, 2] if cz else 1 - f[:, 2])
            )
            acc = acc + w[:, None].to(table.dtype) * tab[rows]
        outs.append(acc)
    return torch.cat(outs, dim=1)


class FusedLayout:
    """Device tensors of a :class:`LevelLayout` for the batched path (cached per device)."""

    def __init__(self, layout: LevelLayout, device: torch.device):
        n = layout.resolutions
        self.res = torch.tensor([float(r) for r in n], dtype=torch.float64, device=device)
        # levels are ordered by resolution, so the dense ones form a prefix
        self.n_dense = sum(layout.dense)
        assert all(layout.dense[: self.n_dense]) and not any(layout.dense[self.n_dense :])
        self.offsets = torch.tensor(layout.offsets, dtype=torch.int32, device=device)
        # per-axis multipliers: dense strides (1, n+1, (n+1)^2) or the hash primes
        self.mult = torch.tensor(
            [[1, r + 1, (r + 1) ** 2] if d else list(PRIMES) for r, d in zip(n, layout.dense, strict=True)],
            dtype=torch.int64,
            device=device,
        )
        self.mask = layout.table_size - 1
        self.total_rows = layout.total_rows


def _as_rows(t: torch.Tensor) -> torch.Tensor:
    """(N, 2) real -> (N,) complex view (one 8/16-byte element per row) for faster index ops."""
    return torch.view_as_complex(t) if t.shape[1] == 2 and t.is_contiguous() else t


def _gather_impl(table: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    src = _as_rows(table)
    out = src.index_select(0, rows)
    return torch.view_as_real(out) if out.is_complex() else out


def _scatter_impl(grad: torch.Tensor, rows: torch.Tensor, n_rows: int) -> torch.Tensor:
    grad = grad.contiguous()
    src = _as_rows(grad)
    acc = torch.zeros((n_rows, *src.shape[1:]), dtype=src.dtype, device=src.device)
    acc.index_add_(0, rows, src)
    return torch.view_as_real(acc) if acc.is_complex() else acc


class _GatherRows(torch.autograd.Function):
    """table[rows] whose backward is :class:`_ScatterRows` (and vice versa): differentiable to
    any order. Same values as ``index_select``; the backward adds rows as complex numbers when
    F = 2 (one index_add element per row), several times faster on CPU than the stock
    ``index_select`` backward."""

    @staticmethod
    def forward(ctx, table: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(rows)
        ctx.n_rows = table.shape[0]
        return _gather_impl(table, rows)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (rows,) = ctx.saved_tensors
        return _ScatterRows.apply(grad, rows, ctx.n_rows), None


class _ScatterRows(torch.autograd.Function):
    @staticmethod
    def forward(ctx, grad: torch.Tensor, rows: torch.Tensor, n_rows: int) -> torch.Tensor:
        ctx.save_for_backward(rows)
        return _scatter_impl(grad, rows, n_rows)

    @staticmethod
    def backward(ctx, gg: torch.Tensor):
        (rows,) = ctx.saved_tensors
        return _GatherRows.apply(gg, rows), None, None


def fused_rows(u: torch.Tensor, fl: FusedLayout) -> tuple[torch.Tensor, torch.Tensor]:
    """Table rows of the 8 corners on every level, and the fractional cell positions.

    Args:
        u: (P, 3) points, already clamped to [0, 1].

    Returns:
        rows (P, Lv, 8) int32 (corner c = 4 cz + 2 cy + cx, level offsets included) and
        frac (P, Lv, 3) in u's dtype (differentiable in u).
    """
    return _rows_frac(u, fl.res.to(u.dtype), fl.mult, fl.offsets, fl.n_dense, fl.mask)


def _rows_frac(
    u: torch.Tensor, res: torch.Tensor, mult: torch.Tensor, offsets: torch.Tensor, n_dense: int, mask: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`fused_rows` on explicit tensors (traceable by torch.compile)."""
    i0, frac = _cell(u[:, None, :], res[None, :, None])  # (P, Lv, 3)
    # Row = combine over axes of (i0_a + c_a) * mult_a: a sum on dense levels, an xor on hashed
    # ones. Multiplying per axis before combining keeps the temporaries at (P, Lv, 3, 2); only
    # the final (P, Lv, 8) index is materialised. Masking each hashed term with T - 1 before
    # the xor is exact because bitwise and distributes over xor.
    # The per-axis terms are < 2^24 after masking, so the combination runs in int32 (half the
    # memory traffic of int64; index_select and index_add accept int32 indices).
    corner = torch.arange(2, device=u.device)
    axes = (i0[..., None] + corner) * mult[None, :, :, None]  # (P, Lv, 3, 2) int64
    parts = []
    if n_dense > 0:
        a = axes[:, :n_dense].to(torch.int32)
        parts.append(a[:, :, 2, :, None, None] + a[:, :, 1, None, :, None] + a[:, :, 0, None, None, :])
    if n_dense < axes.shape[1]:
        a = (axes[:, n_dense:] & mask).to(torch.int32)
        parts.append(a[:, :, 2, :, None, None] ^ a[:, :, 1, None, :, None] ^ a[:, :, 0, None, None, :])
    rows = parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)
    rows = rows.reshape(u.shape[0], res.shape[0], 8) + offsets[None, :, None]
    return rows, frac


def _lerp_forward(
    v: torch.Tensor, frac: torch.Tensor, res: torch.Tensor, with_jacobian: bool
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Trilinear interpolation of gathered corners by nested lerps, and its spatial Jacobian.

    v: (P, Lv, 2z, 2y, 2x, F) corner values; frac: (P, Lv, 3); res: (Lv,).
    Returns out (P, Lv, F) and jac (3, P, Lv, F) (d out / d u_a) or None.
    """
    fx = frac[:, :, 0, None, None, None]
    fy = frac[:, :, 1, None, None]
    fz = frac[:, :, 2, None]
    dx = v[:, :, :, :, 1] - v[:, :, :, :, 0]  # (P, Lv, 2z, 2y, F)
    a = v[:, :, :, :, 0] + fx * dx
    dy = a[:, :, :, 1] - a[:, :, :, 0]  # (P, Lv, 2z, F)
    b = a[:, :, :, 0] + fy * dy
    dz = b[:, :, 1] - b[:, :, 0]  # (P, Lv, F)
    out = b[:, :, 0] + fz * dz
    if not with_jacobian:
        return out, None
    r = res[None, :, None]
    cx = dx[:, :, :, 0] + fy * (dx[:, :, :, 1] - dx[:, :, :, 0])  # lerp_y of the x-differences
    jx = (cx[:, :, 0] + fz * (cx[:, :, 1] - cx[:, :, 0])) * r
    jy = (dy[:, :, 0] + fz * (dy[:, :, 1] - dy[:, :, 0])) * r
    return out, torch.stack((jx, jy, dz * r), 0)


def _lerp_adjoint(
    g_out: torch.Tensor | None, g_jac: torch.Tensor | None, frac: torch.Tensor, res: torch.Tensor
) -> torch.Tensor:
    """Gradient w.r.t. the corner values v of :func:`_lerp_forward` (which is linear in v).

    With per-axis weights W_a = (1 - f_a, f_a) and slopes S_a = res (-1, +1):
    out = Σ Wz Wy Wx v, jac_x = Σ Wz Wy Sx v, jac_y = Σ Wz Sy Wx v, jac_z = Σ Sz Wy Wx v, so
    dv = Wz ⊗ (Wy ⊗ (Wx g_out + Sx g_x) + Sy ⊗ Wx g_y) + Sz ⊗ Wy ⊗ Wx g_z.
    Built from differentiable ops: the backward can itself be differentiated (double backward).
    Returns (P, Lv, 2z, 2y, 2x, F).
    """
    sgn = torch.tensor([-1.0, 1.0], dtype=frac.dtype, device=frac.device)
    w = torch.stack((1 - frac, frac), -1)  # (P, Lv, 3, 2)
    wx, wy, wz = w[:, :, 0, :, None], w[:, :, 1, :, None], w[:, :, 2, :, None]  # (P, Lv, 2, 1)
    sx = sy = sz = (res[:, None] * sgn)[None, :, :, None]  # (1, Lv, 2, 1), same on every axis
    if g_out is None:
        g_out = torch.zeros_like(g_jac[0])
    gx = g_out[:, :, None] * wx  # (P, Lv, 2x, F)
    if g_jac is not None:
        gx = gx + g_jac[0][:, :, None] * sx
    bb = wy[..., None, :] * gx[:, :, None]  # (P, Lv, 2y, 2x, F)
    if g_jac is not None:
        bb = bb + sy[..., None, :] * (g_jac[1][:, :, None] * wx)[:, :, None]
    dv = wz[..., None, None, :] * bb[:, :, None]  # (P, Lv, 2z, 2y, 2x, F)
    if g_jac is not None:
        c = wy[..., None, :] * (g_jac[2][:, :, None] * wx)[:, :, None]
        dv = dv + sz[..., None, None, :] * c[:, :, None]
    return dv


def _kernel_forward(u, table, res, mult, offsets, n_dense: int, mask: int, with_jacobian: bool):
    """Rows, gather and lerps in one function: what torch.compile fuses into one loop."""
    rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
    v = table[rows.long()]  # (P, Lv, 8, F), plain indexing for the compiler
    p, nlev = frac.shape[0], frac.shape[1]
    out, jac = _lerp_forward(v.reshape(p, nlev, 2, 2, 2, table.shape[1]), frac.to(table.dtype),
                             res.to(table.dtype), with_jacobian)
    if jac is None:
        return out, out.new_zeros(0)
    return out, jac


def _kernel_backward(u, g_out, g_jac, n_rows: int, res, mult, offsets, n_dense: int, mask: int, with_jacobian: bool):
    """Recompute rows from u, adjoint of the lerps, scatter-add into a zero table gradient."""
    rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
    dv = _lerp_adjoint(g_out, g_jac if with_jacobian else None, frac.to(g_out.dtype), res.to(g_out.dtype))
    feat = dv.shape[-1]
    g = torch.zeros(n_rows, feat, dtype=dv.dtype, device=dv.device)
    return g.index_put_((rows.reshape(-1).long(),), dv.reshape(-1, feat), accumulate=True)


_COMPILED: dict[str, object] = {}
_COMPILE_BROKEN: list[str] = []


def _compiled(name: str, fn):
    """torch.compile(fn, dynamic=True), built once per process (None after a failure)."""
    if _COMPILE_BROKEN:
        return None
    if name not in _COMPILED:
        _COMPILED[name] = torch.compile(fn, dynamic=True)
    return _COMPILED[name]


def _run_compiled(name: str, fn, *args):
    """Run the compiled kernel, or the eager one if compiling fails (warn once, then stay eager)."""
    cfn = _compiled(name, fn)
    if cfn is not None:
        try:
            return cfn(*args)
        except Exception as exc:  # inductor needs a C++ compiler / Triton; never fail the job
            import warnings

            _COMPILE_BROKEN.append(repr(exc))
            warnings.warn(f"hash encoding: torch.compile failed ({exc!r:.200}); using the eager kernels",
                          RuntimeWarning, stacklevel=3)
    return fn(*args)


class _InterpTable(torch.autograd.Function):
    """Features (and Jacobian) from the table with a hand-written backward to the table.

    Used when the points need no gradient (training: sample points come from geometry). The
    first-order backward is one adjoint pass plus one scatter-add instead of autograd's many
    slice/select backward buffers. When a second derivative is being built (grad mode on in the
    backward) it uses differentiable ops (:func:`_lerp_adjoint` + :class:`_ScatterRows`).

    With ``compiled`` the forward and first-order backward run as torch.compile'd kernels that
    recompute the rows from u instead of saving them (P x 3 floats saved, not P x Lv x 8 ints).
    """

    @staticmethod
    def forward(ctx, table, u, res, mult, offsets, n_dense, mask, with_jacobian, compiled):
        ctx.n_rows = table.shape[0]
        ctx.meta = (n_dense, mask, with_jacobian, compiled)
        if compiled:
            out, jac = _run_compiled("fwd", _kernel_forward, u, table, res, mult, offsets, n_dense, mask,
                                     with_jacobian)
            ctx.save_for_backward(u, res, mult, offsets, None, None)
            return out, jac
        rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
        p, nlev = frac.shape[0], frac.shape[1]
        v = _gather_impl(table, rows.reshape(-1)).reshape(p, nlev, 2, 2, 2, table.shape[1])
        frac = frac.to(table.dtype)
        out, jac = _lerp_forward(v, frac, res.to(table.dtype), with_jacobian)
        ctx.save_for_backward(u, res, mult, offsets, rows, frac)
        return out, (jac if jac is not None else out.new_zeros(0))

    @staticmethod
    def backward(ctx, g_out, g_jac):
        u, res, mult, offsets, rows, frac = ctx.saved_tensors
        n_dense, mask, with_jacobian, compiled = ctx.meta
        if compiled and not torch.is_grad_enabled():
            g_table = _run_compiled("bwd", _kernel_backward, u, g_out.contiguous(),
                                    g_jac.contiguous() if with_jacobian else g_out.new_zeros(0),
                                    ctx.n_rows, res, mult, offsets, n_dense, mask, with_jacobian)
            return g_table, None, None, None, None, None, None, None, None
        if rows is None:
            rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
            frac = frac.to(g_out.dtype)
        dv = _lerp_adjoint(g_out, g_jac if with_jacobian else None, frac, res.to(g_out.dtype))
        g_table = _ScatterRows.apply(dv.reshape(-1, dv.shape[-1]), rows.reshape(-1), ctx.n_rows)
        return g_table, None, None, None, None, None, None, None, None


def encode_fused(
    u: torch.Tensor, table: torch.Tensor, fl: FusedLayout, with_jacobian: bool = False, compiled: bool = False
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Batched encoding: all levels and corners in one gather from the flat table.

    Interpolation is done as nested lerps (x, then y, then z) on the gathered corner values,
    and the spatial Jacobian reuses the same differences, so it costs a few extra lerps. When
    ``u`` needs no gradient a custom autograd function with a hand-written (and itself
    differentiable) backward to the table is used; otherwise plain autograd ops, differentiable
    to any order in both the table and ``u``.

    Args:
        u: (P, 3) points in [0, 1]^3 (clamped here).
        table: (total_rows, F) vertex features.
        fl: device layout.
        with_jacobian: also return the Jacobian.
        compiled: run the no-grad-in-u kernels through ``torch.compile`` (inductor C++ on CPU,
            Triton on CUDA); same values, compiled once per process (tens of seconds on CPU).

    Returns:
        features (P, n_levels * F) and, if asked, the Jacobian as tangents ``(3, P, n_levels *
        F)``: entry ``[a, p, d] = d feature_d / d u_a`` at point p (else None).
    """
    u = u.clamp(0.0, 1.0)
    p, feat = u.shape[0], table.shape[1]
    nlev = fl.res.shape[0]
    if u.requires_grad and torch.is_grad_enabled():
        rows, frac = fused_rows(u, fl)
        v = _GatherRows.apply(table, rows.reshape(-1)).reshape(p, nlev, 2, 2, 2, feat)  # [z, y, x]
        out, jac = _lerp_forward(v, frac.to(table.dtype), fl.res.to(table.dtype), with_jacobian)
    else:
        res = fl.res.to(u.dtype)
        out, jac = _InterpTable.apply(table, u.detach(), res, fl.mult, fl.offsets, fl.n_dense, fl.mask,
                                      with_jacobian, compiled)
        if not with_jacobian:
            jac = None
    out = out.reshape(p, nlev * feat)
    return out, (jac.reshape(3, p, nlev * feat) if jac is not None else None)


class HashEncoding(torch.nn.Module):
    """Multi-resolution hash encoding module.

    Args:
        cfg: grid shape (:class:`HashEncodingConfig`).
        fast: use :func:`encode_fused` (batched) instead of :func:`encode_reference` (loop).
        compiled: with ``fast``, run the fused kernels through torch.compile.

    ``forward(u (P,3) in [0,1]^3) -> (P, cfg.output_dim)``.
    """

    def __init__(self, cfg: HashEncodingConfig | None = None, fast: bool = True, compiled: bool = False):
        super().__init__()
        self.cfg = cfg or CPU_ENCODING
        self.fast = fast
        self.compiled = compiled
        self.layout = LevelLayout(self.cfg)
        self.table = torch.nn.Parameter(
            torch.empty(self.layout.total_rows, self.cfg.n_features).uniform_(-self.cfg.init_scale, self.cfg.init_scale)
        )
        self._fused: dict[tuple[torch.device, torch.dtype], FusedLayout] = {}

    @property
    def output_dim(self) -> int:
        return self.cfg.output_dim

    def fused_layout(self, device: torch.device) -> FusedLayout:
        key = (device, torch.int64)
        if key not in self._fused:
            self._fused[key] = FusedLayout(self.layout, device)
        return self._fused[key]

    def _check(self, u: torch.Tensor) -> None:
        if u.ndim != 2 or u.shape[1] != 3:
            raise ShsasError(f"hash encoding: points must have shape (P, 3), got {tuple(u.shape)}")

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        self._check(u)
        if self.fast:
            return encode_fused(u, self.table, self.fused_layout(u.device), compiled=self.compiled)[0]
        return encode_reference(u, self.table, self.layout)

    def forward_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Features (P, D) and their Jacobian as tangents (3, P, D) = d features / d u_a."""
        self._check(u)
        out, jac = encode_fused(u, self.table, self.fused_layout(u.device), with_jacobian=True,
                                compiled=self.compiled)
        assert jac is not None
        return out, jac
