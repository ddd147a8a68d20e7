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
        self.offsets = torch.tensor(layout.offsets, dtype=torch.int64, device=device)
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
        rows (P, Lv, 8) int64 (corner c = 4 cz + 2 cy + cx, level offsets included) and
        frac (P, Lv, 3) in u's dtype (differentiable in u).
    """
    res = fl.res.to(u.dtype)
    i0, frac = _cell(u[:, None, :], res[None, :, None])  # (P, Lv, 3)
    # Row = combine over axes of (i0_a + c_a) * mult_a: a sum on dense levels, an xor on hashed
    # ones. Multiplying per axis before combining keeps the temporaries at (P, Lv, 3, 2); only
    # the final (P, Lv, 8) index is materialised. Masking each hashed term with T - 1 before
    # the xor is exact because bitwise and distributes over xor.
    corner = torch.arange(2, device=u.device)
    axes = (i0[..., None] + corner) * fl.mult[None, :, :, None]  # (P, Lv, 3, 2)
    nd = fl.n_dense
    parts = []
    if nd > 0:
        a = axes[:, :nd]
        parts.append(a[:, :, 2, :, None, None] + a[:, :, 1, None, :, None] + a[:, :, 0, None, None, :])
    if nd < axes.shape[1]:
        a = axes[:, nd:] & fl.mask
        parts.append(a[:, :, 2, :, None, None] ^ a[:, :, 1, None, :, None] ^ a[:, :, 0, None, None, :])
    rows = parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)
    rows = rows.reshape(u.shape[0], fl.res.shape[0], 8) + fl.offsets[None, :, None]
    return rows, frac


def encode_fused(
    u: torch.Tensor, table: torch.Tensor, fl: FusedLayout, with_jacobian: bool = False
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Batched encoding: all levels and corners in one gather from the flat table.

    Interpolation is done as nested lerps (x, then y, then z) on the gathered corner values,
    and the spatial Jacobian reuses the same differences, so it costs a few extra lerps.

    Args:
        u: (P, 3) points in [0, 1]^3 (clamped here).
        table: (total_rows, F) vertex features.
        fl: device layout.
        with_jacobian: also return the Jacobian.

    Returns:
        features (P, n_levels * F) and, if asked, the Jacobian as tangents ``(3, P, n_levels *
        F)``: entry ``[a, p, d] = d feature_d / d u_a`` at point p (else None).
    """
    u = u.clamp(0.0, 1.0)
    p, feat = u.shape[0], table.shape[1]
    rows, frac = fused_rows(u, fl)
    nlev = rows.shape[1]
    v = _GatherRows.apply(table, rows.reshape(-1)).reshape(p, nlev, 2, 2, 2, feat)  # [z, y, x]
    frac = frac.to(table.dtype)
    fx = frac[:, :, 0, None, None, None]
    fy = frac[:, :, 1, None, None]
    fz = frac[:, :, 2, None]
    dx = v[:, :, :, :, 1] - v[:, :, :, :, 0]  # (P, Lv, 2z, 2y, F)
    a = v[:, :, :, :, 0] + fx * dx
    dy = a[:, :, :, 1] - a[:, :, :, 0]  # (P, Lv, 2z, F)
    b = a[:, :, :, 0] + fy * dy
    dz = b[:, :, 1] - b[:, :, 0]  # (P, Lv, F)
    out = (b[:, :, 0] + fz * dz).reshape(p, nlev * feat)
    if not with_jacobian:
        return out, None
    res = fl.res.to(table.dtype)[None, :, None]
    cx = dx[:, :, :, 0] + fy * (dx[:, :, :, 1] - dx[:, :, :, 0])  # lerp_y of x-differences
    jx = (cx[:, :, 0] + fz * (cx[:, :, 1] - cx[:, :, 0])) * res
    jy = (dy[:, :, 0] + fz * (dy[:, :, 1] - dy[:, :, 0])) * res
    jz = dz * res
    jac = torch.stack((jx, jy, jz), 0).reshape(3, p, nlev * feat)
    return out, jac


class HashEncoding(torch.nn.Module):
    """Multi-resolution hash encoding module.

    Args:
        cfg: grid shape (:class:`HashEncodingConfig`).
        fast: use :func:`encode_fused` (batched) instead of :func:`encode_reference` (loop).

    ``forward(u (P,3) in [0,1]^3) -> (P, cfg.output_dim)``.
    """

    def __init__(self, cfg: HashEncodingConfig | None = None, fast: bool = True):
        super().__init__()
        self.cfg = cfg or CPU_ENCODING
        self.fast = fast
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
            return encode_fused(u, self.table, self.fused_layout(u.device))[0]
        return encode_reference(u, self.table, self.layout)

    def forward_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Features (P, D) and their Jacobian as tangents (3, P, D) = d features / d u_a."""
        self._check(u)
        out, jac = encode_fused(u, self.table, self.fused_layout(u.device), with_jacobian=True)
        assert jac is not None
        return out, jac
