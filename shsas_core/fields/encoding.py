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
* :func:`encode_fused`: all levels and corners in one batched gather (int32 row indices,
  ``index_select``), no Python loop over levels. Optionally also returns the analytic spatial
  Jacobian of the features, d features / d u (P, D, 3), from the same gathered corner values;
  the field uses it to get normals by forward-mode differentiation in the same pass.

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
        t = lambda v, dt: torch.tensor(v, dtype=dt, device=device)  # noqa: E731
        n = layout.resolutions
        self.res_f64 = t([float(r) for r in n], torch.float64)
        self.dense = t(layout.dense, torch.bool)
        self.offsets = t(layout.offsets, torch.int32)
        # per-axis multipliers: dense stride (1, n+1, (n+1)^2) or hash prime
        self.mult = t(
            [[1, r + 1, (r + 1) ** 2] if d else list(PRIMES) for r, d in zip(n, layout.dense, strict=True)],
            torch.int64,
        )
        self.mask = layout.table_size - 1
        self.total_rows = layout.total_rows


def encode_fused(
    u: torch.Tensor, table: torch.Tensor, fl: FusedLayout, with_jacobian: bool = False
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Batched encoding: all levels and corners in one ``index_select`` on the flat table.

    Args:
        u: (P, 3) points in [0, 1]^3 (clamped here).
        table: (total_rows, F) vertex features.
        fl: device layout.
        with_jacobian: also return d features / d u.

    Returns:
        features (P, n_levels * F) and, if asked, the Jacobian (P, n_levels * F, 3) (else None).
    """
    u = u.clamp(0.0, 1.0)
    p = u.shape[0]
    nlev = fl.res_f64.shape[0]
    feat = table.shape[1]
    res = fl.res_f64.to(u.dtype)
    i0, f = _cell(u[:, None, :], res[None, :, None])  # (P, Lv, 3)
    # Row index = combine_axes(axis_term(i0_a + c_a)) with sum for dense levels and xor for
    # hashed ones. Multiplying per axis before combining keeps every temporary at (P, Lv, 2):
    # only the final (P, Lv, 8) index is materialised, in int32. Masking each hashed term with
    # (T - 1) before the xor is exact because bitwise and distributes over xor.
    corner = torch.arange(2, device=u.device)
    axes = (i0[..., None] + corner) * fl.mult[None, :, :, None]  # (P, Lv, 3, 2) int64
    dense = fl.dense[None, :, None, None]
    axes = torch.where(dense, axes, axes & fl.mask).to(torch.int32)
    ax, ay, az = axes[:, :, 0], axes[:, :, 1], axes[:, :, 2]
    # corner order c = 4*cz + 2*cy + cx (same as encode_reference)
    d_rows = az[..., :, None, None] + ay[..., None, :, None] + ax[..., None, None, :]
    h_rows = az[..., :, None, None] ^ ay[..., None, :, None] ^ ax[..., None, None, :]
    rows = torch.where(fl.dense[None, :, None, None, None], d_rows, h_rows).reshape(p, nlev, 8)
    rows = rows + fl.offsets[None, :, None]
    vals = table.index_select(0, rows.reshape(-1)).reshape(p, nlev, 8, feat)

    f = f.to(table.dtype)
    wx = torch.stack((1 - f[..., 0], f[..., 0]), -1)  # (P, Lv, 2)
    wy = torch.stack((1 - f[..., 1], f[..., 1]), -1)
    wz = torch.stack((1 - f[..., 2], f[..., 2]), -1)
    wyz = wz[..., :, None, None] * wy[..., None, :, None]  # (P, Lv, 2, 2, 1)
    w = (wyz * wx[..., None, None, :]).reshape(p, nlev, 8)
    out = (w[..., None] * vals).sum(2).reshape(p, nlev * feat)
    if not with_jacobian:
        return out, None
    # d w / d u_a = res * (product of the other two axis weights) * (+1 or -1 on axis a)
    sgn = torch.tensor([-1.0, 1.0], dtype=table.dtype, device=u.device)
    r = res.to(table.dtype)[None, :, None]
    dwx = (wyz * (sgn * r)[..., None, None, :]).reshape(p, nlev, 8)
    dwy = (wz[..., :, None, None] * (sgn * r)[..., None, :, None] * wx[..., None, None, :]).reshape(p, nlev, 8)
    dwz = ((sgn * r)[..., :, None, None] * wy[..., None, :, None] * wx[..., None, None, :]).reshape(p, nlev, 8)
    dw = torch.stack((dwx, dwy, dwz), -1)  # (P, Lv, 8, 3)
    jac = torch.einsum("plca,plcf->plfa", dw, vals).reshape(p, nlev * feat, 3)
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
        """Features (P, D) and their Jacobian d features / d u (P, D, 3), one gather."""
        self._check(u)
        out, jac = encode_fused(u, self.table, self.fused_layout(u.device), with_jacobian=True)
        assert jac is not None
        return out, jac
