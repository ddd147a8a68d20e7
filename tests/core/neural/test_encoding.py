"""Hash encoding: brute-force per-point reference, fused vs eager, dense levels, derivatives."""

from __future__ import annotations

import math

import pytest
import torch
from pydantic import ValidationError

from shsas_core.common.errors import ShsasError
from shsas_core.neural.fields.encoding import (
    CPU_ENCODING,
    PAPER_GPU_ENCODING,
    FusedLayout,
    HashEncoding,
    HashEncodingConfig,
    LevelLayout,
    encode_fused,
    encode_reference,
    encoding_preset,
)

# 3 dense levels (N = 4, 6, 12 -> (N+1)^3 <= 4096) and 3 hashed ones (N = 21, 36, 64)
SMALL = HashEncodingConfig(n_levels=6, n_features=2, log2_table_size=12, base_resolution=4, finest_resolution=64)
TINY = HashEncodingConfig(n_levels=3, n_features=2, log2_table_size=6, base_resolution=2, finest_resolution=8)


def brute_force(u: list[float], table: list[list[float]], cfg: HashEncodingConfig) -> list[float]:
    """Per-point Instant-NGP encoding written from the paper with Python ints and floats."""
    t = 2**cfg.log2_table_size
    b = math.exp((math.log(cfg.finest_resolution) - math.log(cfg.base_resolution)) / (cfg.n_levels - 1))
    out: list[float] = []
    offset = 0
    for lvl in range(cfg.n_levels):
        n = math.floor(cfg.base_resolution * b**lvl + 1e-6)
        dense = (n + 1) ** 3 <= t
        pos = [min(max(c, 0.0), 1.0) * n for c in u]
        lo = [min(math.floor(p), n - 1) for p in pos]
        fr = [p - q for p, q in zip(pos, lo, strict=True)]
        acc = [0.0] * cfg.n_features
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    i, j, k = lo[0] + dx, lo[1] + dy, lo[2] + dz
                    if dense:
                        row = i + j * (n + 1) + k * (n + 1) ** 2
                    else:  # uint32 arithmetic, then mod T
                        row = ((i * 1) ^ (j * 2654435761) ^ (k * 805459861)) % 2**32 % t
                    w = (fr[0] if dx else 1 - fr[0]) * (fr[1] if dy else 1 - fr[1]) * (fr[2] if dz else 1 - fr[2])
                    for f in range(cfg.n_features):
                        acc[f] += w * table[offset + row][f]
        out += acc
        offset += (n + 1) ** 3 if dense else t
    return out


def _random_table(layout: LevelLayout, feat: int, dtype=torch.float64, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(layout.total_rows, feat, generator=g, dtype=dtype) * 2 - 1


def _points(p: int, dtype=torch.float64, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(p, 3, generator=g, dtype=dtype)
    # the cube's faces and corners too (u = 0 and u = 1 exactly)
    u[:4] = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5], [0.5, 1.0, 0.0]], dtype=dtype)
    return u


def test_levels_and_presets() -> None:
    lay = LevelLayout(SMALL)
    assert lay.resolutions == [4, 6, 12, 21, 36, 64]
    assert lay.dense == [True, True, True, False, False, False]
    assert PAPER_GPU_ENCODING.resolutions()[0] == 16 and PAPER_GPU_ENCODING.resolutions()[-1] == 4096
    assert PAPER_GPU_ENCODING.n_levels == 16 and PAPER_GPU_ENCODING.log2_table_size == 19
    assert PAPER_GPU_ENCODING.output_dim == 32
    assert CPU_ENCODING.resolutions()[-1] == CPU_ENCODING.finest_resolution
    assert encoding_preset("paper_gpu") is PAPER_GPU_ENCODING
    with pytest.raises(ShsasError, match="unknown"):
        encoding_preset("huge")
    with pytest.raises(ValidationError):
        HashEncodingConfig(base_resolution=64, finest_resolution=32)


def test_reference_matches_brute_force() -> None:
    lay = LevelLayout(SMALL)
    table = _random_table(lay, SMALL.n_features)
    u = _points(40)
    ref = encode_reference(u, table, lay)
    tl = table.tolist()
    brute = torch.tensor([brute_force(p, tl, SMALL) for p in u.tolist()], dtype=torch.float64)
    torch.testing.assert_close(ref, brute, rtol=0, atol=1e-12)


def test_fused_matches_reference_values_and_grads() -> None:
    lay = LevelLayout(SMALL)
    fl = FusedLayout(lay, torch.device("cpu"))
    table = _random_table(lay, SMALL.n_features).requires_grad_(True)
    u = _points(500).requires_grad_(True)
    w = torch.randn(500, SMALL.output_dim, dtype=torch.float64)
    ref = encode_reference(u, table, lay)
    fus, _ = encode_fused(u, table, fl)
    torch.testing.assert_close(fus, ref, rtol=0, atol=1e-12)
    g_ref = torch.autograd.grad((ref * w).sum(), (table, u))
    g_fus = torch.autograd.grad((fus * w).sum(), (table, u))
    for a, b in zip(g_fus, g_ref, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-10)


def test_custom_table_backward_matches_reference() -> None:
    # u without grad -> the hand-written backward (_InterpTable); check it against autograd of
    # the reference for the features and for the Jacobian (via the composite fused path).
    lay = LevelLayout(SMALL)
    fl = FusedLayout(lay, torch.device("cpu"))
    u = _points(400)
    w = torch.randn(400, SMALL.output_dim, dtype=torch.float64)
    wj = torch.randn(3, 400, SMALL.output_dim, dtype=torch.float64)
    t_ref = _random_table(lay, SMALL.n_features).requires_grad_(True)
    t_fus = t_ref.detach().clone().requires_grad_(True)
    (g_ref,) = torch.autograd.grad((encode_reference(u, t_ref, lay) * w).sum(), t_ref)
    out, none = encode_fused(u, t_fus, fl)
    assert none is None
    (g_fus,) = torch.autograd.grad((out * w).sum(), t_fus)
    torch.testing.assert_close(g_fus, g_ref, rtol=0, atol=1e-10)
    # with the Jacobian: compare against the composite path (u requiring grad)
    o1, j1 = encode_fused(u, t_fus, fl, with_jacobian=True)
    o2, j2 = encode_fused(u.clone().requires_grad_(True), t_fus, fl, with_jacobian=True)
    torch.testing.assert_close(o1, o2, rtol=0, atol=1e-12)
    torch.testing.assert_close(j1, j2, rtol=0, atol=1e-10)
    ga = torch.autograd.grad((o1 * w).sum() + (j1 * wj).sum(), t_fus)[0]
    gb = torch.autograd.grad((o2 * w).sum() + (j2 * wj).sum(), t_fus)[0]
    torch.testing.assert_close(ga, gb, rtol=0, atol=1e-10)


def test_custom_table_backward_gradgradcheck() -> None:
    lay = LevelLayout(TINY)
    fl = FusedLayout(lay, torch.device("cpu"))
    table = _random_table(lay, TINY.n_features).requires_grad_(True)
    u = torch.rand(5, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(4))

    def f(tab: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out, jac = encode_fused(u, tab, fl, with_jacobian=True)
        return out, jac

    assert torch.autograd.gradcheck(f, (table,))
    assert torch.autograd.gradgradcheck(f, (table,))


def test_fused_float32_matches() -> None:
    enc = HashEncoding(SMALL, backend="fused")
    enc.table.data.uniform_(-1, 1)
    u = _points(300, dtype=torch.float32)
    ref = encode_reference(u, enc.table, enc.layout)
    torch.testing.assert_close(enc(u), ref, rtol=0, atol=1e-6)


def test_fused_jacobian_matches_autograd() -> None:
    lay = LevelLayout(SMALL)
    fl = FusedLayout(lay, torch.device("cpu"))
    table = _random_table(lay, SMALL.n_features)
    u = _points(30)[4:]  # interior points: the Jacobian of a face point is one-sided
    _, jac = encode_fused(u, table, fl, with_jacobian=True)
    full = torch.autograd.functional.jacobian(lambda v: encode_reference(v, table, lay), u)  # (P,D,P,3)
    idx = torch.arange(u.shape[0])
    torch.testing.assert_close(jac, full[idx, :, idx, :].permute(2, 0, 1), rtol=0, atol=1e-10)


def test_dense_levels_are_collision_free() -> None:
    lay = LevelLayout(SMALL)
    fl = FusedLayout(lay, torch.device("cpu"))
    for lvl, (n, dense) in enumerate(zip(lay.resolutions, lay.dense, strict=True)):
        if not dense:
            continue
        # one point per grid vertex: its corner 0 is that vertex (the last layer uses corner 1)
        g = torch.arange(n + 1, dtype=torch.float64) / n
        verts = torch.cartesian_prod(g, g, g)
        table = torch.zeros(lay.total_rows, 1, dtype=torch.float64)
        rows = torch.arange(lay.sizes[lvl], dtype=torch.float64)
        table[lay.offsets[lvl] : lay.offsets[lvl] + lay.sizes[lvl], 0] = rows
        cfg1 = SMALL.model_copy(update={"n_features": 1})
        out, _ = encode_fused(verts, table, FusedLayout(LevelLayout(cfg1), fl.res.device))
        got = out[:, lvl].round().long()
        assert got.unique().numel() == (n + 1) ** 3 == lay.sizes[lvl]
        assert got.min() == 0 and got.max() == lay.sizes[lvl] - 1


def test_hashed_levels_use_whole_table() -> None:
    lay = LevelLayout(SMALL)
    assert all(s == 2**SMALL.log2_table_size for s, d in zip(lay.sizes, lay.dense, strict=True) if not d)
    assert lay.total_rows == sum(lay.sizes)


def test_continuous_at_upper_face() -> None:
    lay = LevelLayout(SMALL)
    table = _random_table(lay, SMALL.n_features)
    u1 = torch.tensor([[1.0, 0.3, 0.7]], dtype=torch.float64)
    u0 = torch.tensor([[1.0 - 1e-12, 0.3, 0.7]], dtype=torch.float64)
    torch.testing.assert_close(encode_reference(u1, table, lay), encode_reference(u0, table, lay), atol=1e-9, rtol=0)


@pytest.mark.parametrize("fast", [False, True])
def test_gradcheck_and_gradgradcheck(fast: bool) -> None:
    lay = LevelLayout(TINY)
    fl = FusedLayout(lay, torch.device("cpu"))
    table = _random_table(lay, TINY.n_features).requires_grad_(True)
    u = (torch.rand(5, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(3)) * 0.9 + 0.05)
    u.requires_grad_(True)

    def f(tab: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
        return encode_fused(pts, tab, fl)[0] if fast else encode_reference(pts, tab, lay)

    assert torch.autograd.gradcheck(f, (table, u))
    assert torch.autograd.gradgradcheck(f, (table, u))
    if fast:  # the Jacobian output is itself differentiable (used by forward-mode normals)
        assert torch.autograd.gradcheck(lambda t, p: encode_fused(p, t, fl, True)[1], (table, u))


def test_module_shapes_and_errors() -> None:
    for backend in ("reference", "fused", "native"):  # compiled: test_fields (slow)
        enc = HashEncoding(SMALL, backend=backend)
        assert enc.table.shape == (LevelLayout(SMALL).total_rows, 2)
        assert enc(torch.rand(7, 3)).shape == (7, SMALL.output_dim)
        assert enc(torch.rand(0, 3)).shape == (0, SMALL.output_dim)
        with pytest.raises(ShsasError, match=r"\(P, 3\)"):
            enc(torch.rand(7, 2))
    assert float(HashEncoding(SMALL).table.detach().abs().max()) <= SMALL.init_scale
    with pytest.raises(ShsasError, match="unknown backend 'fast'"):
        HashEncoding(SMALL, backend="fast")


@pytest.mark.gpu
def test_fused_matches_reference_on_cuda() -> None:
    enc = HashEncoding(SMALL, backend="fused").cuda()
    enc.table.data.uniform_(-1, 1)
    u = torch.rand(10_000, 3, device="cuda")
    torch.testing.assert_close(enc(u), encode_reference(u, enc.table, enc.layout), rtol=0, atol=1e-6)
