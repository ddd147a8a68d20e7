"""The Triton hash-encoding kernels against the eager reference, run by Triton's interpreter on
the CPU (``TRITON_INTERPRET=1``, set per test: the kernels are built on first use, so the setting
may change after import). Sizes are tiny: the interpreter runs each program in Python."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("triton", reason="Triton is not installed (pip install triton; CUDA torch ships it)")

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox
from shsas_core.neural.fields import SHField
from shsas_core.neural.fields import encoding_triton as et
from shsas_core.neural.fields.config import FieldConfig
from shsas_core.neural.fields.encoding import (
    FusedLayout,
    HashEncoding,
    HashEncodingConfig,
    LevelLayout,
    encode_fused,
    encode_reference,
)

# resolutions 2, 3 (dense: 27 and 64 vertices in 64 rows), 6 and 12 (hashed into 64 rows)
TINY = HashEncodingConfig(n_levels=4, n_features=2, log2_table_size=6, base_resolution=2, finest_resolution=12)
# 16 rows per level: every level hashed, hundreds of vertices per row
CROWDED = HashEncodingConfig(n_levels=3, n_features=3, log2_table_size=4, base_resolution=3, finest_resolution=20)
CPU = torch.device("cpu")


@pytest.fixture(autouse=True)
def interpreter(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TRITON_INTERPRET", "1")


def _case(cfg: HashEncodingConfig, p: int, dtype: torch.dtype = torch.float64, seed: int = 0):
    lay = LevelLayout(cfg)
    g = torch.Generator().manual_seed(seed)
    table = torch.rand(lay.total_rows, cfg.n_features, generator=g, dtype=dtype) * 2 - 1
    u = torch.rand(p, 3, generator=g, dtype=dtype)
    # the cube's corners and faces (u = 0 and 1, where the last cell is clamped), and cell faces:
    # 0.25, 0.5 and 0.75 times N are integers on the levels N = 2 (0.5), 12 (all) and 6 (0.5)
    edge = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5], [0.5, 1.0, 0.0], [0.25, 0.5, 0.75],
            [0.5, 0.5, 0.5], [0.75, 0.25, 1.0]]
    u[: len(edge)] = torch.tensor(edge, dtype=dtype)[:p]
    return lay, FusedLayout(lay, CPU), table, u


def _reference_with_jacobian(u: torch.Tensor, table: torch.Tensor, lay: LevelLayout):
    """Reference features and their Jacobian (3, P, D) by autograd, differentiable again."""
    out = encode_reference(u, table, lay)
    cols = [torch.autograd.grad(out[:, d].sum(), u, create_graph=True)[0] for d in range(out.shape[1])]
    return out, torch.stack(cols, -1).permute(1, 0, 2)  # points are independent: a column's sum


def _grads(fn, u, table, go, gj):
    tab = table.clone().requires_grad_(True)
    pts = u.clone().requires_grad_(True)
    out, jac = fn(pts, tab)
    g_tab, g_u = torch.autograd.grad((out * go).sum() + (jac * gj).sum(), (tab, pts))
    return out.detach(), jac.detach(), g_tab, g_u


@pytest.mark.parametrize("cfg", [TINY, CROWDED], ids=["dense+hashed", "collisions"])
def test_values_jacobian_and_both_gradients_match_the_reference(cfg: HashEncodingConfig) -> None:
    lay, fl, table, u = _case(cfg, 60)
    g = torch.Generator().manual_seed(5)
    go = torch.randn(60, cfg.output_dim, generator=g, dtype=torch.float64)
    gj = torch.randn(3, 60, cfg.output_dim, generator=g, dtype=torch.float64)
    got = _grads(lambda p, t: et.encode_triton(p, t, fl, with_jacobian=True), u, table, go, gj)
    ref = _grads(lambda p, t: _reference_with_jacobian(p, t, lay), u, table, go, gj)
    for name, a, b in zip(("features", "jacobian", "table gradient", "points gradient"), got, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10, msg=name)
    if cfg is CROWDED:  # the case is what its name says: distinct vertices share table rows
        n = lay.resolutions[-1]
        lo = torch.minimum(torch.floor(u * n), torch.tensor(n - 1.0)).long()
        verts = {tuple((lo[p] + torch.tensor(c)).tolist()) for p in range(60)
                 for c in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1))}
        assert len(verts) > 4 * lay.sizes[-1]


def test_without_jacobian_and_one_gradient_at_a_time() -> None:
    lay, fl, table, u = _case(TINY, 30, seed=2)
    go = torch.randn(30, TINY.output_dim, dtype=torch.float64)
    tab = table.clone().requires_grad_(True)
    out, none = et.encode_triton(u, tab, fl)
    assert none is None
    (g_tab,) = torch.autograd.grad((out * go).sum(), tab)
    t_ref = table.clone().requires_grad_(True)
    (g_ref,) = torch.autograd.grad((encode_reference(u, t_ref, lay) * go).sum(), t_ref)
    torch.testing.assert_close(g_tab, g_ref, rtol=1e-10, atol=1e-10)
    pts = u.clone().requires_grad_(True)  # the points alone (a frozen table)
    (g_u,) = torch.autograd.grad((et.encode_triton(pts, table, fl)[0] * go).sum(), pts)
    p_ref = u.clone().requires_grad_(True)
    (g_u_ref,) = torch.autograd.grad((encode_reference(p_ref, table, lay) * go).sum(), p_ref)
    torch.testing.assert_close(g_u, g_u_ref, rtol=1e-10, atol=1e-10)


def test_gradcheck_and_double_backward_in_float64() -> None:
    _, fl, table, _ = _case(TINY, 6, seed=3)
    u = 0.05 + 0.9 * torch.rand(6, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64)  # no kinks
    table.requires_grad_(True)
    u.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t, p: et.encode_triton(p, t, fl, True), (table, u), fast_mode=True)
    # create_graph: the backward recomputes the PyTorch fused ops (the kernel's is not differentiable)
    assert torch.autograd.gradgradcheck(lambda t, p: et.encode_triton(p, t, fl, True), (table, u),
                                        fast_mode=True)


def test_float32_matches_the_reference() -> None:
    lay, fl, table, u = _case(TINY, 200, dtype=torch.float32, seed=4)
    go = torch.randn(200, TINY.output_dim)
    gj = torch.randn(3, 200, TINY.output_dim)
    out, jac, g_tab, g_u = _grads(lambda p, t: et.encode_triton(p, t, fl, True), u, table, go, gj)
    # float32 cells as the kernel's (a float64 reference would put u * N elsewhere by ~N eps)
    torch.testing.assert_close(out, encode_reference(u, table, lay), rtol=0, atol=1e-6)
    ref = _grads(lambda p, t: encode_fused(p, t, fl, True, use_native=False), u, table, go, gj)
    torch.testing.assert_close(jac, ref[1], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(g_tab, ref[2], rtol=1e-5, atol=1e-5 * float(ref[2].abs().max()))
    torch.testing.assert_close(g_u, ref[3], rtol=1e-5, atol=1e-5 * float(ref[3].abs().max()))


def test_non_finite_points_read_the_origin_cell() -> None:
    lay, fl, table, u = _case(TINY, 20, seed=6)
    bad = u.clone()
    bad[10] = float("nan")
    bad[11, 1] = float("inf")
    bad[12, 2] = -float("inf")
    tab = table.clone().requires_grad_(True)
    out, jac = et.encode_triton(bad, tab, fl, with_jacobian=True)
    fixed = bad.nan_to_num(nan=0.0).clamp(0.0, 1.0)
    torch.testing.assert_close(out, encode_reference(fixed, table, lay), rtol=0, atol=1e-12)
    (g,) = torch.autograd.grad(out.sum() + jac.sum(), tab)
    assert torch.isfinite(jac).all() and torch.isfinite(g).all()


def test_no_points() -> None:
    _, fl, table, _ = _case(TINY, 10)
    tab = table.clone().requires_grad_(True)
    out, jac = et.encode_triton(torch.zeros(0, 3, dtype=torch.float64), tab, fl, True)
    assert out.shape == (0, TINY.output_dim) and jac.shape == (3, 0, TINY.output_dim)
    (g,) = torch.autograd.grad(out.sum() + jac.sum(), tab)
    assert not g.any()


def test_unsupported_tensors_are_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    _, fl, table, u = _case(TINY, 10)
    # bfloat16 is used nowhere in the field; the kernels refuse it rather than round silently
    with pytest.raises(ShsasError, match="triton.*bfloat16"):
        et.encode_triton(u.bfloat16(), table.bfloat16(), fl)
    with pytest.raises(ShsasError, match="points in torch.float32 and table in torch.float64"):
        et.encode_triton(u.float(), table, fl)
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    with pytest.raises(ShsasError, match="TRITON_INTERPRET=1"):
        et.encode_triton(u, table, fl)
    enc = HashEncoding(TINY, backend="triton")
    with pytest.raises(ShsasError, match="backend 'triton'.*CPU tensors"):
        enc(u.float())


def test_native_never_takes_triton_on_cpu() -> None:
    enc = HashEncoding(TINY, backend="native")
    u = torch.rand(5, 3)
    assert not et.usable(u, enc.table)  # not even under the interpreter
    assert not enc._triton(u)


def test_field_on_the_triton_backend_equals_fused() -> None:
    box = SceneBox(min=(-0.2, -0.1, 0.0), max=(0.2, 0.1, 0.25))
    torch.manual_seed(0)
    fields = [SHField(FieldConfig(sh_degree=1, encoding=TINY, scene_box=box, hidden=8, backend=b)).double()
              for b in ("fused", "triton")]
    fields[1].load_state_dict(fields[0].state_dict())
    g = torch.Generator().manual_seed(1)
    x = torch.tensor(box.min, dtype=torch.float64) + torch.rand(40, 3, generator=g, dtype=torch.float64) * (
        torch.tensor(box.max, dtype=torch.float64) - torch.tensor(box.min, dtype=torch.float64))
    x[0] = torch.tensor([0.5, 0.0, 0.1])  # outside the box
    d = torch.nn.functional.normalize(torch.randn(40, 3, generator=g, dtype=torch.float64), dim=1)
    res = []
    for f in fields:
        out = f(x, d)
        loss = (out["density"] * out["normals"][:, 2]).sum() + out["scattering"].abs().sum()
        grads = torch.autograd.grad(loss, list(f.parameters()))
        res.append(([out[k].detach() for k in ("density", "scattering", "normals", "gradient")], grads))
    for a, b in zip(res[0][0] + list(res[0][1]), res[1][0] + list(res[1][1]), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)


@pytest.mark.gpu
def test_compiled_kernels_match_the_reference_on_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    cfg = HashEncodingConfig(n_levels=6, n_features=2, log2_table_size=12, base_resolution=4, finest_resolution=64)
    lay, _, table, u = _case(cfg, 50_000, dtype=torch.float32)
    fl = FusedLayout(lay, torch.device("cuda"))
    table, u = table.cuda(), u.cuda()
    go = torch.randn(50_000, cfg.output_dim, device="cuda")
    gj = torch.randn(3, 50_000, cfg.output_dim, device="cuda")
    enc = HashEncoding(cfg, backend="native").cuda()
    assert enc._triton(u)  # on CUDA the default backend takes the kernels
    got = _grads(lambda p, t: et.encode_triton(p, t, fl, True), u, table, go, gj)
    ref = _grads(lambda p, t: encode_fused(p, t, fl, True), u, table, go, gj)
    torch.testing.assert_close(got[0], encode_reference(u, table, lay), rtol=0, atol=1e-6)
    for a, b in zip(got[1:], ref[1:], strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5 * float(b.abs().max()))


def test_kernels_compile_for_a_gpu_without_one(monkeypatch: pytest.MonkeyPatch) -> None:
    # the interpreter runs any Python; the compiler is stricter. Triton's wheel brings ptxas, so
    # the kernels can be compiled for an H100 (sm_90) on a machine without a GPU
    import triton
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    ptrs = {n: "*fp32" for n in ("u_ptr", "tab_ptr", "res_ptr", "out_ptr", "jac_ptr", "gtab_ptr", "gu_ptr")}
    sig = {**ptrs, "mult_ptr": "*i64", "off_ptr": "*i64", "P": "i32", "n_dense": "i32", "mask": "i32",
           **{k: "constexpr" for k in ("F", "NL", "JAC", "BACKWARD", "NEED_TABLE", "NEED_U", "BLOCK")}}
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    for backward in (False, True):  # the forward with the Jacobian; the backward with every output
        const = {"F": 2, "NL": 16, "JAC": True, "BACKWARD": backward, "NEED_TABLE": backward,
                 "NEED_U": backward, "BLOCK": et.BLOCK_POINTS}
        kernel = triton.compile(ASTSource(triton.jit(et._hash_kernel), sig, const),
                                target=GPUTarget("cuda", 90, 32))
        assert kernel.asm["cubin"]
