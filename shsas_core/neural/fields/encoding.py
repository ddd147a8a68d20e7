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
* :func:`encode_fused`: all levels and corners in one batched gather per feature (1-D
  ``index_select`` with int32 rows, feature-major layout; its backward a matching ``index_add``),
  no Python loop over levels, nested lerps instead of 8 corner weights. Optionally also returns the analytic spatial
  Jacobian of the features (as tangents (3, P, D)) from the same gathered corner values; the
  field contracts it with d|c_00|/d features to get normals in the same pass.

Both are built from differentiable torch ops only, so they are differentiable to any order with
respect to the table and the input (double backward for create_graph normals works).
"""

from __future__ import annotations

import math
from typing import Literal, get_args

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator

from shsas_core.common.errors import ShsasError
from shsas_core.neural.fields import native

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
    log2_table_size: int = Field(17, ge=4, le=24, description="log2 of the table rows per level")
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
#: CPU default: 12 levels x 2 features, N_min 16, N_max 512, 2^17 rows per level (~2.3 M params).
#: Not 2^15: its hashed levels held 6-4,100x more vertices than rows, and the collision speckle
#: cost the neural methods fidelity; not 2^19: slower for no more (docs/decisions/hash-table-size.md).
CPU_ENCODING = HashEncodingConfig()

#: Small (CPU, short runs): 8 levels, N_min 8, N_max 128, 2^13 rows per level; the setting the
#: trainer's sphere convergence test uses (the job spec's ``encoding="small"``).
SMALL_ENCODING = HashEncodingConfig(n_levels=8, log2_table_size=13, base_resolution=8, finest_resolution=128)

#: Every named preset; the job spec's ``encoding`` names one of these (a test checks they agree).
PRESETS: dict[str, HashEncodingConfig] = {"paper_gpu": PAPER_GPU_ENCODING, "cpu": CPU_ENCODING,
                                          "small": SMALL_ENCODING}


def encoding_preset(name: str) -> HashEncodingConfig:
    """The named preset (``paper_gpu``, ``cpu`` or ``small``)."""
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
        self._native: native.NativeLayout | None = None

    def native_layout(self) -> native.NativeLayout:
        """The arrays of the C kernel (CPU), built once."""
        if self._native is None:
            self._native = native.NativeLayout(self.res, self.mult, self.offsets, self.n_dense, self.mask)
        return self._native


# ---------------------------------------------------------------------------------------------
# Fused path. Everything is laid out feature-major and corner-major with (P, Lv) innermost:
# rows (8, P, Lv), corner values (F, 2z, 2y, 2x, P, Lv), fractions (3, P, Lv). Then every
# elementwise op broadcasts over leading axes and runs over long contiguous inner loops, and the
# gather/scatter are 1-D index_select/index_add with int32 indices (the fast CPU kernels);
# a feature-minor layout (inner axis F = 2) was several times slower in eager PyTorch.


def fused_rows(u: torch.Tensor, fl: FusedLayout) -> tuple[torch.Tensor, torch.Tensor]:
    """Table rows of the 8 corners on every level, and the fractional cell positions.

    Args:
        u: (P, 3) points, already clamped to [0, 1].

    Returns:
        rows (8, P, Lv) int32 (corner c = 4 cz + 2 cy + cx, level offsets included) and
        frac (3, P, Lv) in u's dtype (differentiable in u).
    """
    return _rows_frac(u, fl.res.to(u.dtype), fl.mult, fl.offsets, fl.n_dense, fl.mask)


def _rows_frac(
    u: torch.Tensor, res: torch.Tensor, mult: torch.Tensor, offsets: torch.Tensor, n_dense: int, mask: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`fused_rows` on explicit tensors (traceable by torch.compile)."""
    xs = u.t()[:, :, None] * res  # (3, P, Lv)
    lo = torch.minimum(torch.floor(xs), res - 1).clamp_min(0)  # last cell at u = 1, see _cell
    frac = xs - lo
    # Row = combine over axes of (i0_a + c_a) * mult_a: a sum on dense levels, an xor on hashed
    # ones (levels are sorted by resolution, so the dense ones are a prefix). Multiplying per
    # axis before combining keeps the temporaries at (2, 3, P, Lv); masking each hashed term
    # with T - 1 before the xor is exact because bitwise and distributes over xor. After the
    # mask every term is < 2^24, so the combination runs in int32.
    corner = torch.arange(2, device=u.device).view(2, 1, 1, 1)
    axes = (lo.long()[None] + corner) * mult.t()[None, :, None, :]  # (2, 3, P, Lv) int64
    parts = []
    if n_dense > 0:
        a = axes[..., :n_dense].to(torch.int32)
        parts.append(a[:, 2][:, None, None] + a[:, 1][None, :, None] + a[:, 0][None, None, :])
    if n_dense < axes.shape[-1]:
        a = (axes[..., n_dense:] & mask).to(torch.int32)
        parts.append(a[:, 2][:, None, None] ^ a[:, 1][None, :, None] ^ a[:, 0][None, None, :])
    rows = parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)  # (2z, 2y, 2x, P, Lv)
    rows = (rows + offsets).reshape(8, u.shape[0], res.shape[0])
    return rows, frac


def _gather(table: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    """Corner values (F, 2z, 2y, 2x, P, Lv) of table (N, F) at rows (8, P, Lv)."""
    tab_t = table.t().contiguous()  # (F, N): one 1-D gather per feature
    flat = rows.reshape(-1)
    feat = tab_t.shape[0]
    if torch.is_grad_enabled() or torch.compiler.is_compiling():  # inductor: no out= into views
        v = torch.stack([tab_t[f].index_select(0, flat) for f in range(feat)])
    else:  # gather straight into the output (no stack copy); out= is not differentiable
        v = tab_t.new_empty((feat, flat.shape[0]))
        for f in range(feat):
            torch.index_select(tab_t[f], 0, flat, out=v[f])
    return v.reshape(feat, 2, 2, 2, *rows.shape[1:])


def _scatter(dv: torch.Tensor, rows: torch.Tensor, n_rows: int) -> torch.Tensor:
    """Adjoint of :func:`_gather`: (F, 2, 2, 2, P, Lv) values added into a zero (N, F) table."""
    flat = rows.reshape(-1)
    feat = dv.shape[0]
    if torch.is_grad_enabled():
        cols = [dv.new_zeros(n_rows).index_add(0, flat, dv[f].reshape(-1)) for f in range(feat)]
        return torch.stack(cols, 1)
    acc = dv.new_zeros((feat, n_rows))
    for f in range(feat):
        acc[f].index_add_(0, flat, dv[f].reshape(-1))
    return acc.t()


def _lerp_forward(
    v: torch.Tensor, frac: torch.Tensor, res: torch.Tensor, with_jacobian: bool
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Trilinear interpolation of gathered corners by nested lerps, and its spatial Jacobian.

    v: (F, 2z, 2y, 2x, P, Lv) corner values; frac: (3, P, Lv); res: (Lv,).
    Returns out (F, P, Lv) and jac (3, F, P, Lv) (d out / d u_a), or None.
    """
    fx, fy, fz = frac[0], frac[1], frac[2]
    if not with_jacobian:  # torch.lerp: one kernel per level of the tree
        a = torch.lerp(v[:, :, :, 0], v[:, :, :, 1], fx)  # (F, 2z, 2y, P, Lv)
        b = torch.lerp(a[:, :, 0], a[:, :, 1], fy)  # (F, 2z, P, Lv)
        return torch.lerp(b[:, 0], b[:, 1], fz), None
    dx = v[:, :, :, 1] - v[:, :, :, 0]  # (F, 2z, 2y, P, Lv)
    a = torch.addcmul(v[:, :, :, 0], fx, dx)
    dy = a[:, :, 1] - a[:, :, 0]  # (F, 2z, P, Lv)
    b = torch.addcmul(a[:, :, 0], fy, dy)
    dz = b[:, 1] - b[:, 0]  # (F, P, Lv)
    out = torch.addcmul(b[:, 0], fz, dz)
    cx = torch.lerp(dx[:, :, 0], dx[:, :, 1], fy)  # lerp_y of the x-differences, (F, 2z, P, Lv)
    jac = torch.stack((torch.lerp(cx[:, 0], cx[:, 1], fz), torch.lerp(dy[:, 0], dy[:, 1], fz), dz), 0)
    return out, jac * res


def _lerp_adjoint(
    g_out: torch.Tensor, g_jac: torch.Tensor | None, frac: torch.Tensor, res: torch.Tensor
) -> torch.Tensor:
    """Gradient w.r.t. the corner values v of :func:`_lerp_forward` (which is linear in v).

    With per-axis weights W_a = (1 - f_a, f_a) and slopes S = res (-1, +1):
    out = Σ Wz Wy Wx v, jac_x = Σ Wz Wy S v, jac_y = Σ Wz S Wx v, jac_z = Σ S Wy Wx v, so
    dv = Wz ⊗ (Wy ⊗ (Wx g_out + S g_x) + S ⊗ Wx g_y) + S ⊗ Wy ⊗ Wx g_z.
    g_out: (F, P, Lv); g_jac: (3, F, P, Lv) or None. Built from differentiable ops, so this
    backward can itself be differentiated (double backward). Returns (F, 2z, 2y, 2x, P, Lv).
    """
    # Each axis splits a gradient g into (1 - f) g + ... and f g + ...; the (1 - f) half is
    # computed as g - (f half), which halves the number of full-size products.
    fx, fy, fz = frac[0], frac[1], frac[2]
    if g_jac is not None and not torch.is_grad_enabled() and not torch.compiler.is_compiling():
        return _lerp_adjoint_into(g_out, g_jac, fx, fy, fz, res)

    def split(total: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
        return torch.stack((total - upper, upper), 1)

    if g_jac is None:
        gx = split(g_out, g_out * fx)  # (F, 2x, P, Lv)
        bb = split(gx, fy * gx)  # (F, 2y, 2x, P, Lv)
        return split(bb, fz * bb)  # (F, 2z, 2y, 2x, P, Lv)
    gjx, gjy, gjz = g_jac[0], g_jac[1], g_jac[2]
    # x: W g_out + S g_jx, with S = res (-1, +1): the lower half is g_out - upper
    gx = split(g_out, torch.addcmul(g_out * fx, gjx, res.expand_as(gjx)))
    hy = split(gjy, gjy * fx)  # Wx g_jy
    bb = split(gx, torch.addcmul(fy * gx, hy, res.expand_as(hy)))  # Wy gx + S (Wx g_jy)
    kx = split(gjz, gjz * fx)  # Wx g_jz
    cc = split(kx, fy * kx)  # Wy Wx g_jz
    return split(bb, torch.addcmul(fz * bb, cc, res.expand_as(cc)))  # Wz bb + S cc


def _lerp_adjoint_into(g_out: torch.Tensor, g_jac: torch.Tensor, fx: torch.Tensor, fy: torch.Tensor,
                      fz: torch.Tensor, res: torch.Tensor) -> torch.Tensor:
    """:func:`_lerp_adjoint` with a Jacobian, writing every level of the tree into its slot of
    one preallocated output instead of stacking halves (no graph: first-order backward only).

    Each axis writes its upper half, ``f g + S h``, then turns the lower slot, which holds the
    total ``g``, into ``g - upper``; the (F, 2, 2, 2, P, Lv) result is built without copies.
    """
    feat, p, nlev = g_out.shape
    dv = g_out.new_empty((feat, 2, 2, 2, p, nlev))
    gjx, gjy, gjz = g_jac[0], g_jac[1], g_jac[2]
    low_z = dv[:, 0]  # holds bb = Wy ⊗ (Wx g_out + S g_x) + S ⊗ Wx g_y until the z split
    gx = low_z[:, 0]  # holds Wx g_out + S g_x (F, 2x, P, Lv) until the y split
    torch.mul(g_out, fx, out=gx[:, 1])
    gx[:, 1].addcmul_(gjx, res)
    torch.sub(g_out, gx[:, 1], out=gx[:, 0])
    hy = torch.stack((gjy, gjy * fx), 1)  # Wx g_jy: lower half fixed below
    hy[:, 0].sub_(hy[:, 1])
    torch.mul(gx, fy[None], out=low_z[:, 1])
    low_z[:, 1].addcmul_(hy, res)
    gx.sub_(low_z[:, 1])
    kx = torch.stack((gjz, gjz * fx), 1)
    kx[:, 0].sub_(kx[:, 1])
    cc = torch.stack((kx, kx * fy[None]), 1)  # Wy ⊗ Wx g_jz
    cc[:, 0].sub_(cc[:, 1])
    torch.mul(low_z, fz[None, None], out=dv[:, 1])
    dv[:, 1].addcmul_(cc, res)
    low_z.sub_(dv[:, 1])
    return dv


def _to_point_major(out: torch.Tensor, jac: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """(F, P, Lv) -> (P, Lv*F) level-major features; (3, F, P, Lv) -> (3, P, Lv*F) (or empty)."""
    feat, p, nlev = out.shape
    o = out.permute(1, 2, 0).reshape(p, nlev * feat)
    if jac is None:
        return o, out.new_zeros(0)
    return o, jac.permute(0, 2, 3, 1).reshape(3, p, nlev * feat)


def _to_feature_major(g: torch.Tensor, nlev: int) -> torch.Tensor:
    """Inverse of :func:`_to_point_major` for gradients: (..., P, Lv*F) -> (..., F, P, Lv)."""
    g = g.reshape(*g.shape[:-1], nlev, g.shape[-1] // nlev)  # (..., P, Lv, F)
    return g.movedim(-1, -3).contiguous()


def _kernel_forward(u, table, res, mult, offsets, n_dense: int, mask: int, with_jacobian: bool):
    """Rows, gather, lerps: what torch.compile fuses into a few loops."""
    rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
    out, jac = _lerp_forward(_gather(table, rows), frac.to(table.dtype), res.to(table.dtype), with_jacobian)
    return _to_point_major(out, jac)


def _kernel_backward(u, g_out, g_jac, n_rows: int, res, mult, offsets, n_dense: int, mask: int,
                     with_jacobian: bool):
    """Recompute rows from u, adjoint of the lerps, scatter-add into a zero table gradient."""
    rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
    nlev = res.shape[0]
    go = _to_feature_major(g_out, nlev)
    gj = _to_feature_major(g_jac, nlev) if with_jacobian else None
    dv = _lerp_adjoint(go, gj, frac.to(go.dtype), res.to(go.dtype))
    return _scatter(dv, rows, n_rows)


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
    backward is one adjoint pass plus one index_add per feature, instead of autograd's many
    slice/select backward buffers. It is built from differentiable ops, so a double backward
    (create_graph) through it works.

    With ``compiled`` the forward and the first-order backward run as torch.compile'd kernels
    that recompute the rows from u instead of saving them.
    """

    @staticmethod
    def forward(ctx, table, u, res, mult, offsets, n_dense, mask, with_jacobian, compiled, nl):
        ctx.n_rows = table.shape[0]
        ctx.meta = (n_dense, mask, with_jacobian, compiled, nl)
        if nl is not None:  # the C kernel (CPU, float32): rows are recomputed in its backward
            ctx.save_for_backward(u, res, mult, offsets, None, None)
            return native.forward(u, table, nl, with_jacobian)
        if compiled:
            ctx.save_for_backward(u, res, mult, offsets, None, None)
            return _run_compiled("fwd", _kernel_forward, u, table, res, mult, offsets, n_dense, mask,
                                 with_jacobian)
        rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
        frac = frac.to(table.dtype)
        out, jac = _lerp_forward(_gather(table, rows), frac, res.to(table.dtype), with_jacobian)
        ctx.save_for_backward(u, res, mult, offsets, rows, frac)
        return _to_point_major(out, jac)

    @staticmethod
    def backward(ctx, g_out, g_jac):
        u, res, mult, offsets, rows, frac = ctx.saved_tensors
        n_dense, mask, with_jacobian, compiled, nl = ctx.meta
        none = (None,) * 9
        if nl is not None and not torch.is_grad_enabled():
            g_table = native.backward(u, g_out, g_jac if with_jacobian else None, nl, ctx.n_rows,
                                      g_out.shape[1] // res.shape[0])
            return (g_table, *none)
        if compiled and not torch.is_grad_enabled():
            g_table = _run_compiled("bwd", _kernel_backward, u, g_out.contiguous(),
                                    g_jac.contiguous() if with_jacobian else g_out.new_zeros(0),
                                    ctx.n_rows, res, mult, offsets, n_dense, mask, with_jacobian)
            return (g_table, *none)
        if rows is None:
            rows, frac = _rows_frac(u, res, mult, offsets, n_dense, mask)
            frac = frac.to(g_out.dtype)
        nlev = res.shape[0]
        go = _to_feature_major(g_out, nlev)
        gj = _to_feature_major(g_jac, nlev) if with_jacobian else None
        dv = _lerp_adjoint(go, gj, frac, res.to(g_out.dtype))
        return (_scatter(dv, rows, ctx.n_rows), *none)


def encode_fused(
    u: torch.Tensor, table: torch.Tensor, fl: FusedLayout, with_jacobian: bool = False, compiled: bool = False,
    use_native: bool = True,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Batched encoding: all levels and corners in one gather per feature from the flat table.

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
        use_native: on float32 CPU tensors, run the no-grad-in-u forward and first-order
            backward in the C kernel of :mod:`.native` when it builds (it takes precedence over
            ``compiled``); same values. A double backward falls back to the PyTorch ops.

    Returns:
        features (P, n_levels * F) and, if asked, the Jacobian as tangents ``(3, P, n_levels *
        F)``: entry ``[a, p, d] = d feature_d / d u_a`` at point p (else None).
    """
    u = u.clamp(0.0, 1.0)
    if u.requires_grad and torch.is_grad_enabled():
        rows, frac = fused_rows(u, fl)
        out, jac = _lerp_forward(_gather(table, rows), frac.to(table.dtype), fl.res.to(table.dtype),
                                 with_jacobian)
        out, jac = _to_point_major(out, jac)
    else:
        nl = fl.native_layout() if use_native and native.usable(u, table) else None
        out, jac = _InterpTable.apply(table, u.detach(), fl.res.to(u.dtype), fl.mult, fl.offsets, fl.n_dense,
                                      fl.mask, with_jacobian, compiled, nl)
    return out, (jac if with_jacobian else None)


#: How the encoding (and the field around it) is computed; every backend gives the same values.
#: ``reference``: per-level Python loop (the test oracle; normals by double backward in the field);
#: ``fused``: all levels in one gather, with the analytic Jacobian, in PyTorch ops; ``native``
#: (the device's own kernel): ``fused`` with the C kernel of :mod:`.native` on float32 CPU
#: tensors when it builds, with the Triton kernels of :mod:`.encoding_triton` on float32/float64
#: CUDA tensors when Triton imports, elsewhere ``fused``; ``triton``: always the Triton kernels
#: (CUDA, or CPU under ``TRITON_INTERPRET=1``; a clear error otherwise); ``compiled``: ``fused``
#: through ``torch.compile`` (20-60 s to compile on a 2-core CPU, no faster there).
Backend = Literal["reference", "fused", "native", "triton", "compiled"]
BACKENDS: tuple[str, ...] = get_args(Backend)


class HashEncoding(torch.nn.Module):
    """Multi-resolution hash encoding module.

    Args:
        cfg: grid shape (:class:`HashEncodingConfig`).
        backend: one of :data:`BACKENDS` (same values, see there).

    ``forward(u (P,3) in [0,1]^3) -> (P, cfg.output_dim)``.
    """

    def __init__(self, cfg: HashEncodingConfig | None = None, backend: Backend = "native"):
        super().__init__()
        if backend not in BACKENDS:
            raise ShsasError(f"hash encoding: unknown backend {backend!r} (one of {', '.join(BACKENDS)})")
        self.cfg = cfg or CPU_ENCODING
        self.backend = backend
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

    def _triton(self, u: torch.Tensor) -> bool:
        """Whether this call runs the Triton kernels: always for ``triton``; for ``native`` on
        the tensors they take on CUDA (imported only then: the CPU path never loads Triton)."""
        if self.backend == "triton":
            return True
        if self.backend != "native" or u.device.type != "cuda":
            return False
        from shsas_core.neural.fields import encoding_triton

        return encoding_triton.usable(u, self.table)

    def _encode(self, u: torch.Tensor, with_jacobian: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        self._check(u)
        fl = self.fused_layout(u.device)
        if self._triton(u):
            from shsas_core.neural.fields.encoding_triton import encode_triton

            return encode_triton(u, self.table, fl, with_jacobian)
        return encode_fused(u, self.table, fl, with_jacobian=with_jacobian, compiled=self.backend == "compiled",
                            use_native=self.backend == "native")

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        if self.backend == "reference":
            self._check(u)
            return encode_reference(u, self.table, self.layout)
        return self._encode(u, False)[0]

    def forward_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Features (P, D) and their Jacobian as tangents (3, P, D) = d features / d u_a."""
        out, jac = self._encode(u, True)
        assert jac is not None
        return out, jac
