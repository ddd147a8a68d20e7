"""The C hash-encoding kernel against the eager reference, its threads, its build and fallback."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from shsas_core.neural.fields import native
from shsas_core.neural.fields.encoding import (
    FusedLayout,
    HashEncodingConfig,
    LevelLayout,
    encode_fused,
    encode_reference,
)

# 3 dense levels and 3 hashed ones (as in test_encoding.SMALL)
SMALL = HashEncodingConfig(n_levels=6, n_features=2, log2_table_size=12, base_resolution=4, finest_resolution=64)
ROOT = Path(__file__).resolve().parents[3]


def _case(p: int, feat: int = 2, cfg: HashEncodingConfig = SMALL, seed: int = 0):
    lay = LevelLayout(cfg)
    g = torch.Generator().manual_seed(seed)
    table = torch.rand(lay.total_rows, feat, generator=g) * 2 - 1
    u = torch.rand(p, 3, generator=g)
    # faces and corners of the cube, where the last cell is clamped
    u[:4] = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5], [0.5, 1.0, 0.0]])
    return lay, FusedLayout(lay, torch.device("cpu")), table, u


def _torch_path(u, table, fl, go, gj):
    """Features, Jacobian and table gradient from the PyTorch fused ops (same float32 cells)."""
    tab = table.clone().requires_grad_(True)
    out, jac = encode_fused(u, tab, fl, with_jacobian=True, use_native=False)
    (g,) = torch.autograd.grad((out * go).sum() + (jac * gj).sum(), tab)
    return out, jac, g


def test_kernel_is_built_on_this_machine() -> None:
    assert native.available(), f"C kernel unavailable: {native._state.get('error')}"


@pytest.mark.parametrize("threads", [1, 2])
def test_forward_jacobian_and_backward_match_the_reference(threads: int) -> None:
    lay, fl, table, u = _case(40000)  # > 2 x 16384 points: the work is split between threads
    go = torch.randn(40000, SMALL.output_dim)
    gj = torch.randn(3, 40000, SMALL.output_dim)
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        tab = table.clone().requires_grad_(True)
        out, jac = encode_fused(u, tab, fl, with_jacobian=True, use_native=True)
        (g,) = torch.autograd.grad((out * go).sum() + (jac * gj).sum(), tab)
    finally:
        torch.set_num_threads(old)
    # float32 cells as the kernel's (a float64 reference puts u * N_l elsewhere by ~N_l eps)
    torch.testing.assert_close(out, encode_reference(u, table, lay), rtol=0, atol=1e-6)
    _, jac_t, g_t = _torch_path(u, table, fl, go, gj)
    # the Jacobian carries the level resolution (up to 64) as a factor
    torch.testing.assert_close(jac, jac_t, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(g, g_t, rtol=1e-5, atol=1e-5 * float(g_t.abs().max()))


def test_backward_without_jacobian_and_odd_feature_count() -> None:
    cfg = HashEncodingConfig(n_levels=4, n_features=3, log2_table_size=9, base_resolution=3, finest_resolution=40)
    lay, fl, table, u = _case(5000, feat=3, cfg=cfg, seed=3)
    go = torch.randn(5000, cfg.output_dim)
    tab = table.clone().requires_grad_(True)
    out, none = encode_fused(u, tab, fl, use_native=True)
    assert none is None
    (g,) = torch.autograd.grad((out * go).sum(), tab)
    t_ref = table.clone().requires_grad_(True)
    (g_ref,) = torch.autograd.grad((encode_reference(u, t_ref, lay) * go).sum(), t_ref)
    torch.testing.assert_close(g, g_ref, rtol=1e-5, atol=1e-4)


def test_same_threads_same_bits() -> None:
    _, fl, table, u = _case(40000, seed=5)
    go = torch.randn(40000, SMALL.output_dim)
    gj = torch.randn(3, 40000, SMALL.output_dim)
    grads = []
    for _ in range(2):
        tab = table.clone().requires_grad_(True)
        out, jac = encode_fused(u, tab, fl, with_jacobian=True, use_native=True)
        grads.append(torch.autograd.grad((out * go).sum() + (jac * gj).sum(), tab)[0])
    assert torch.equal(grads[0], grads[1])  # static split + private tables: no atomics, no races


def test_double_backward_falls_back_to_the_torch_ops() -> None:
    # create_graph needs a differentiable backward: the kernel's is not, so the PyTorch adjoint
    # runs; the second-order gradient must equal the all-PyTorch one
    _, fl, table, u = _case(300, seed=7)
    gj = torch.randn(3, 300, SMALL.output_dim)
    res = []
    for use in (True, False):
        tab = table.clone().requires_grad_(True)
        out, jac = encode_fused(u, tab, fl, with_jacobian=True, use_native=use)
        (g,) = torch.autograd.grad((jac * gj).sum() + (out**2).sum(), tab, create_graph=True)
        (gg,) = torch.autograd.grad((g**2).sum(), tab)
        res.append(gg)
    torch.testing.assert_close(res[0], res[1], rtol=1e-4, atol=1e-3)


def test_non_finite_points_cannot_index_outside_the_table() -> None:
    # a NaN survives clamp(0, 1); cast to an integer it would be an out-of-bounds row (a crash,
    # not an exception, in C): the kernel reads the origin's cell instead
    lay, fl, table, u = _case(50)
    bad = u.clone()
    bad[10] = float("nan")
    bad[11, 1] = float("inf")
    bad[12, 2] = -float("inf")
    tab = table.clone().requires_grad_(True)
    out, jac = encode_fused(bad, tab, fl, with_jacobian=True, use_native=True)
    assert torch.isfinite(out).all() and torch.isfinite(jac).all()
    fixed = bad.nan_to_num(nan=0.0).clamp(0.0, 1.0)
    torch.testing.assert_close(out, encode_reference(fixed, table, lay), rtol=0, atol=1e-6)
    (g,) = torch.autograd.grad(out.sum() + jac.sum(), tab)
    assert torch.isfinite(g).all()


def test_float64_takes_the_torch_path() -> None:
    # the kernel is float32 only: float64 must agree with the reference to float64 precision
    lay, fl, table, u = _case(100)
    assert native.usable(u, table)
    assert not native.usable(u.double(), table.double())
    out, _ = encode_fused(u.double(), table.double(), fl, use_native=True)
    torch.testing.assert_close(out, encode_reference(u.double(), table.double(), lay), rtol=0, atol=1e-12)


def _run(code: str, env: dict[str, str], tmp: Path) -> subprocess.CompletedProcess:
    # both cache directories (SHSAS_CACHE_DIR and the temporary fallback) under this test's tmp
    (tmp / "tmp").mkdir(exist_ok=True)
    full = {**os.environ, "PYTHONPATH": str(ROOT), "SHSAS_CACHE_DIR": str(tmp), "TMPDIR": str(tmp / "tmp"), **env}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, env=full,
                          timeout=300)


CHECK = """
    import warnings, torch
    warnings.simplefilter("always")
    from shsas_core.neural.fields import native
    from shsas_core.neural.fields.encoding import HashEncoding, HashEncodingConfig, encode_reference
    enc = HashEncoding(HashEncodingConfig(n_levels=3, log2_table_size=8, base_resolution=2, finest_resolution=20))
    u = torch.rand(64, 3)
    err = (enc(u) - encode_reference(u, enc.table, enc.layout)).abs().max().item()
    print("available", native.available(), "err", err)
"""


def test_build_goes_to_the_cache_dir(tmp_path: Path) -> None:
    res = _run(CHECK, {}, tmp_path)
    assert res.returncode == 0, res.stderr
    assert "available True" in res.stdout
    built = list((tmp_path / "native").glob("hashgrid-*.so"))
    assert len(built) == 1
    # a second process reuses the build, even with no compiler and a read-only cache
    mtime = built[0].stat().st_mtime_ns
    (tmp_path / "native").chmod(0o555)
    try:
        again = _run(CHECK, {"CC": "", "PATH": "/nonexistent"}, tmp_path)
    finally:
        (tmp_path / "native").chmod(0o755)
    assert "available True" in again.stdout, again.stderr
    assert built[0].stat().st_mtime_ns == mtime


@pytest.mark.parametrize("env, reason", [({"SHSAS_NATIVE": "0"}, None),
                                         ({"CC": "", "PATH": "/nonexistent"}, "no C compiler found")])
def test_without_the_kernel_the_encoding_still_works(tmp_path: Path, env: dict[str, str], reason: str | None) -> None:
    res = _run(CHECK, env, tmp_path)
    assert res.returncode == 0, res.stderr
    assert "available False" in res.stdout
    assert float(res.stdout.split("err")[1]) < 1e-6
    if reason:  # told once why, not a traceback
        assert res.stderr.count(reason) == 1 and "Traceback" not in res.stderr
