"""SHField: formulas, fast vs eager, normals of an analytic sphere, L = 0, derivatives."""

from __future__ import annotations

import math

import pytest
import torch
from pydantic import ValidationError

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox
from shsas_core.neural.fields import HashEncodingConfig, SHField, normals_by_autograd, sh_basis
from shsas_core.neural.fields import field as field_module
from shsas_core.neural.fields.config import FieldConfig

BOX = SceneBox(min=(-0.2, -0.1, 0.0), max=(0.2, 0.1, 0.25))  # not a cube: axis scaling matters
ENC = HashEncodingConfig(n_levels=4, n_features=2, log2_table_size=10, base_resolution=4, finest_resolution=32,
                         init_scale=0.5)
TINY_ENC = HashEncodingConfig(n_levels=2, n_features=2, log2_table_size=6, base_resolution=2, finest_resolution=5,
                              init_scale=0.5)


def _pair(degree: int = 3, enc: HashEncodingConfig = ENC, **kw) -> tuple[SHField, SHField]:
    """An eager and a fast field with the same (float64) parameters."""
    torch.manual_seed(0)
    eager = SHField(FieldConfig(sh_degree=degree, encoding=enc, scene_box=BOX, backend="reference", **kw)).double()
    fast = SHField(FieldConfig(sh_degree=degree, encoding=enc, scene_box=BOX, backend="native", **kw)).double()
    with torch.no_grad():  # random output weights: every coefficient (not only the DC bias) matters
        eager.linears[-1].weight.normal_(0.0, 0.3)
    fast.load_state_dict(eager.state_dict())
    return eager, fast


def _inside(p: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    lo, hi = torch.tensor(BOX.min, dtype=torch.float64), torch.tensor(BOX.max, dtype=torch.float64)
    return lo + (hi - lo) * (0.02 + 0.96 * torch.rand(p, 3, generator=g, dtype=torch.float64))


def _dirs(p: int, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(p, 3, generator=g, dtype=torch.float64), dim=1)


def _loss(out: dict[str, torch.Tensor]) -> torch.Tensor:
    # uses every output, normals included, like the renderer's Lambertian term
    lam = out["normals"] @ torch.tensor([0.3, -0.5, 0.8], dtype=out["density"].dtype)
    return (out["density"] * lam).sum() + (out["scattering"] * lam).abs().sum() + out["dc"].real.sum()


def test_outputs_follow_the_formulas() -> None:
    field, _ = _pair(3, zeta=2.5)
    x, d = _inside(50), _dirs(50)
    c = field.coefficients(x)
    assert c.shape == (50, 16) and c.is_complex()
    torch.testing.assert_close(field.density(x), c[:, 0].abs() / math.sqrt(4 * math.pi) * 2.5)
    y = sh_basis(d, 3)
    expected = (c * y.to(c.dtype)).sum(1)
    torch.testing.assert_close(field.scattering(x, d), expected)
    out = field(x, d)
    torch.testing.assert_close(out["scattering"], expected)
    torch.testing.assert_close(out["dc"], c[:, 0] / math.sqrt(4 * math.pi))
    torch.testing.assert_close(out["density"], field.density(x))
    torch.testing.assert_close(out["normals"], field.normals(x))
    assert "normals" not in field(x, d, with_normals=False)
    # the gradient the normal is made of: ∇|σ_DC| by autograd of the density (ζ divided out)
    xg = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(field.density(xg).sum() / 2.5, xg)
    torch.testing.assert_close(out["gradient"], grad)
    torch.testing.assert_close(out["normals"], -torch.nn.functional.normalize(grad, dim=1))


def test_fast_matches_eager_values_and_parameter_grads() -> None:
    eager, fast = _pair(3)
    x, d = _inside(300), _dirs(300)
    a, b = eager(x, d), fast(x, d)
    for k in ("density", "dc", "scattering", "normals", "gradient"):
        torch.testing.assert_close(b[k], a[k], rtol=0, atol=1e-10)
    torch.testing.assert_close(fast.normals(x), eager.normals(x), rtol=0, atol=1e-10)
    ga = torch.autograd.grad(_loss(a), list(eager.parameters()))
    gb = torch.autograd.grad(_loss(b), list(fast.parameters()))
    for p, q in zip(gb, ga, strict=True):
        torch.testing.assert_close(p, q, rtol=0, atol=1e-9)


def test_fast_matches_eager_input_grads() -> None:
    eager, fast = _pair(2)
    d = _dirs(40)
    xa = _inside(40).requires_grad_(True)
    xb = xa.detach().clone().requires_grad_(True)
    (ga,) = torch.autograd.grad(_loss(eager(xa, d)), xa)
    (gb,) = torch.autograd.grad(_loss(fast(xb, d)), xb)
    torch.testing.assert_close(gb, ga, rtol=0, atol=1e-9)


def test_outside_box_is_empty() -> None:
    for field in _pair(3):
        nan = float("nan")
        x = torch.tensor([[0.3, 0.0, 0.1], [0.0, 0.0, -0.01], [0.0, 0.5, 0.3], [nan, 0.0, 0.1],
                          [-1e30, 0.0, 0.1], [0.0, 0.0, 0.1]], dtype=torch.float64)
        out = field(x, _dirs(6))
        assert torch.all(out["density"][:5] == 0) and out["density"][5] > 0
        assert torch.all(out["scattering"][:5] == 0)
        assert torch.all(out["normals"][:5] == 0)
        assert torch.all(field.coefficients(x)[:5] == 0)
        empty = field(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.float64))
        assert empty["density"].shape == (0,) and empty["normals"].shape == (0, 3)


def test_isotropic_l0() -> None:
    field = SHField(FieldConfig(sh_degree=0, encoding=ENC, scene_box=BOX)).double()
    assert field.coefficients(_inside(3)).shape == (3, 1)
    assert field.linears[-1].out_features == 2
    x = _inside(20).repeat(3, 1)
    d = _dirs(60)
    s = field.scattering(x, d).reshape(3, 20)
    torch.testing.assert_close(s[1], s[0], rtol=0, atol=1e-15)
    torch.testing.assert_close(s[2], s[0], rtol=0, atol=1e-15)
    # σ = c_00 Y_00 = σ_DC
    torch.testing.assert_close(field(x, d)["scattering"], field(x, d)["dc"])


def _radial_field(fast: bool, center: torch.Tensor, big: float) -> SHField:
    """A field whose Re c_00 = big - |x - c|^2 at the grid vertices (one dense level, N = 31).

    The MLP passes the single feature through (ReLU stays active since big > max |x - c|^2).
    """
    enc = HashEncodingConfig(n_levels=1, n_features=1, log2_table_size=15, base_resolution=31,
                             finest_resolution=31)
    field = SHField(FieldConfig(sh_degree=1, encoding=enc, scene_box=BOX, hidden=4, layers=2,
                                backend="native" if fast else "reference")).double()
    n = 31
    g = torch.arange(n + 1, dtype=torch.float64) / n
    k, j, i = torch.meshgrid(g, g, g, indexing="ij")  # row = i + j (n+1) + k (n+1)^2
    u = torch.stack([i.ravel(), j.ravel(), k.ravel()], 1)
    xv = torch.tensor(BOX.min, dtype=torch.float64) + u * torch.tensor(BOX.size, dtype=torch.float64)
    with torch.no_grad():
        field.encoding.table[:, 0] = big - ((xv - center) ** 2).sum(1)
        for lin in field.linears:
            lin.weight.zero_()
            lin.bias.zero_()
        field.linears[0].weight[0, 0] = 1.0
        field.linears[1].weight[0, 0] = 1.0
        field.linears[2].weight[0, 0] = 1.0  # Re c_00
    return field


@pytest.mark.parametrize("fast", [False, True])
def test_normals_of_analytic_sphere_point_outward(fast: bool) -> None:
    center = torch.tensor([0.01, -0.02, 0.12], dtype=torch.float64)
    field = _radial_field(fast, center, big=1.0)
    # Trilinear interpolation of x^2 has the exact slope 2x at cell midpoints, so at points whose
    # coordinates are all cell midpoints the interpolated gradient is exactly radial.
    n = 31
    g = torch.Generator().manual_seed(0)
    cells = torch.randint(0, n, (200, 3), generator=g)
    u = (cells.double() + 0.5) / n
    x = torch.tensor(BOX.min, dtype=torch.float64) + u * torch.tensor(BOX.size, dtype=torch.float64)
    keep = (x - center).norm(dim=1) > 0.02
    x = x[keep]
    nrm = field.normals(x)
    radial = torch.nn.functional.normalize(x - center, dim=1)
    ang = torch.rad2deg(torch.arccos((nrm * radial).sum(1).clamp(-1, 1)))
    assert float(ang.max()) < 1.0
    torch.testing.assert_close(nrm.norm(dim=1), torch.ones(len(x), dtype=torch.float64))


def test_normals_helper_on_analytic_function() -> None:
    center = torch.tensor([0.1, 0.2, -0.3], dtype=torch.float64)
    x = center + torch.randn(100, 3, dtype=torch.float64)
    n = normals_by_autograd(lambda p: torch.exp(-((p - center) ** 2).sum(1)), x)
    radial = torch.nn.functional.normalize(x - center, dim=1)
    ang = torch.rad2deg(torch.arccos((n * radial).sum(1).clamp(-1, 1)))
    assert float(ang.max()) < 1.0
    # zero gradient -> zero normal, not NaN
    assert torch.all(normals_by_autograd(lambda p: p.sum(1) * 0 + 1.0, x) == 0)


def test_zero_field_gives_finite_zero_normals_and_grads() -> None:
    for field in _pair(3):
        with torch.no_grad():
            field.encoding.table.zero_()
            for lin in field.linears:
                lin.weight.zero_()
                lin.bias.zero_()
        x, d = _inside(10), _dirs(10)
        out = field(x, d)
        assert torch.all(out["normals"] == 0) and torch.all(out["density"] == 0)
        grads = torch.autograd.grad(_loss(out), list(field.parameters()), allow_unused=True)
        assert all(gr is None or torch.isfinite(gr).all() for gr in grads)


@pytest.mark.parametrize("fast", [False, True])
def test_gradcheck_field(fast: bool) -> None:
    torch.manual_seed(0)
    field = SHField(FieldConfig(sh_degree=2, encoding=TINY_ENC, scene_box=BOX, hidden=6,
                                backend="native" if fast else "reference")).double()
    with torch.no_grad():  # move away from the tiny init so every term is exercised
        field.linears[-1].weight.normal_()
    x = _inside(4).requires_grad_(True)
    d = _dirs(4).requires_grad_(True)
    table = field.encoding.table

    def scatter(xx, dd, _tab):
        s = field.scattering(xx, dd)
        return torch.view_as_real(s)

    assert torch.autograd.gradcheck(scatter, (x, d, table))
    assert torch.autograd.gradcheck(lambda xx, _t: field.density(xx), (x, table))
    # normals with create_graph are differentiable in parameters and points
    assert torch.autograd.gradcheck(lambda xx, _t: field.normals(xx, create_graph=True), (x, table))
    assert torch.autograd.gradgradcheck(lambda xx, _t: field.density(xx), (x, table))


def test_initial_density_low_but_nonzero() -> None:
    field = SHField(FieldConfig(scene_box=BOX, init_density=0.02))
    x = _inside(1000).float()
    rho = field.density(x).detach()
    assert torch.all(rho > 0.01) and torch.all(rho < 0.04)
    s = field.scattering(x, _dirs(1000).float()).detach().abs()
    assert float(s.max()) < 0.5


def _hidden_on_shares(seed: int) -> list[torch.Tensor]:
    """Per hidden layer, the share of 4,096 box points at which each unit of a new field is on."""
    torch.manual_seed(seed)
    field = SHField(FieldConfig(scene_box=BOX))
    with torch.no_grad():
        u, _inside_box = field._unit(_inside(4096, seed=seed).float())
        h = field._encode(u)
        on = []
        for hidden in field.linears[:-1]:
            h = torch.relu(hidden(h))
            on.append((h > 0).double().mean(0))
    return on


@pytest.mark.parametrize("seed", range(5))
def test_hidden_bias_init_decides_which_units_start_off_everywhere(seed: int, monkeypatch) -> None:
    """At initialisation the table is near 0, so a hidden unit's input is its bias: torch's draw
    (the default) leaves units off at every point of the box, zero biases leave none."""
    assert any(bool((share == 0).any()) for share in _hidden_on_shares(seed))
    monkeypatch.setattr(field_module, "HIDDEN_BIAS_INIT", 0.0)
    on = _hidden_on_shares(seed)
    assert (on[0] > 0.25).all(), on[0]  # the first layer's units split the box about in half
    for share in on[1:]:
        assert (share > 0).all(), share


def test_no_grad_inference_and_shapes() -> None:
    field = SHField(FieldConfig(scene_box=BOX))
    x, d = _inside(64).float(), _dirs(64).float()
    for backend in ("reference", "native"):
        field.cfg = field.cfg.model_copy(update={"backend": backend})
        field.encoding.backend = backend
        with torch.no_grad():
            out = field(x, d)
            n = field.normals(x)
        assert not any(v.requires_grad for v in out.values()) and not n.requires_grad
        assert out["normals"].shape == (64, 3) and out["scattering"].dtype == torch.complex64
        torch.testing.assert_close(n, out["normals"])


def test_bad_input() -> None:
    field = SHField(FieldConfig(scene_box=BOX))
    with pytest.raises(ShsasError, match=r"x must have shape \(P, 3\)"):
        field.density(torch.zeros(4, 2))
    with pytest.raises(ShsasError, match=r"dirs must have shape"):
        field(torch.zeros(4, 3), torch.zeros(4))
    with pytest.raises(ValidationError):
        FieldConfig(sh_degree=4)
    with pytest.raises(ValidationError):
        FieldConfig(zeta=0)


def test_config_json_and_state_dict_round_trip() -> None:
    # what a checkpoint stores: the config as JSON and the state dict
    field, _ = _pair(2, zeta=1.5)
    cfg = FieldConfig.model_validate_json(field.cfg.model_dump_json())
    assert cfg == field.cfg
    again = SHField(cfg).double()
    again.load_state_dict(field.state_dict())
    x, d = _inside(20), _dirs(20)
    for k, v in field(x, d).items():
        torch.testing.assert_close(again(x, d)[k], v, rtol=0, atol=0)


@pytest.mark.gpu
def test_fast_matches_eager_on_cuda() -> None:
    eager, fast = (f.float().cuda() for f in _pair(3))
    x, d = _inside(4096).float().cuda(), _dirs(4096).float().cuda()
    a, b = eager(x, d), fast(x, d)
    for k in ("density", "scattering"):
        torch.testing.assert_close(b[k], a[k], rtol=1e-4, atol=1e-5)
    ok = a["density"] > 1e-3
    assert float((a["normals"][ok] * b["normals"][ok]).sum(1).min()) > 0.999


@pytest.mark.slow
def test_compiled_kernels_match_fused_eager() -> None:
    # torch.compile of the encoding kernels (tens of seconds on 2 cores): same values and grads
    _, fast = _pair(3)
    comp = SHField(FieldConfig(sh_degree=3, encoding=ENC, scene_box=BOX, backend="compiled")).double()
    comp.load_state_dict(fast.state_dict())
    for p in (300, 257):  # a second size must not need a new compile to be right
        x, d = _inside(p, seed=p), _dirs(p, seed=p)
        a, b = fast(x, d), comp(x, d)
        for k in ("density", "dc", "scattering", "normals"):
            torch.testing.assert_close(b[k], a[k], rtol=0, atol=1e-10)
        ga = torch.autograd.grad(_loss(a), list(fast.parameters()))
        gb = torch.autograd.grad(_loss(b), list(comp.parameters()))
        for u, v in zip(gb, ga, strict=True):
            torch.testing.assert_close(u, v, rtol=0, atol=1e-9)
    # the compiled kernels really ran: a compile failure falls back to the eager ones with a
    # warning, which would make the comparisons above trivially true
    from shsas_core.neural.fields import encoding

    assert not encoding._COMPILE_BROKEN, encoding._COMPILE_BROKEN


def test_directional_scale_multiplies_only_the_degree_ge_1_coefficients() -> None:
    torch.manual_seed(0)
    plain = SHField(FieldConfig(sh_degree=2, encoding=ENC, scene_box=BOX, directional_scale=1.0)).double()
    scaled = SHField(FieldConfig(sh_degree=2, encoding=ENC, scene_box=BOX, directional_scale=0.1)).double()
    scaled.load_state_dict(plain.state_dict())
    x, d = _inside(200), _dirs(200)
    c1, c2 = plain.coefficients(x), scaled.coefficients(x)
    torch.testing.assert_close(c2[:, 0], c1[:, 0], rtol=0, atol=0)
    torch.testing.assert_close(c2[:, 1:], 0.1 * c1[:, 1:], rtol=1e-12, atol=0)
    # density and normals come from c_00 alone: unchanged
    a, b = plain(x, d), scaled(x, d)
    for k in ("density", "dc", "normals"):
        torch.testing.assert_close(b[k], a[k], rtol=0, atol=1e-12)
    # σ(ω) = c_00 Y_00 + 0.1 Σ_{l>=1} c_lm Y_lm
    y = sh_basis(d, 2).to(torch.float64)
    want = c1[:, 0] * y[:, 0] + 0.1 * (c1[:, 1:] * y[:, 1:]).sum(1)
    torch.testing.assert_close(b["scattering"], want, rtol=1e-10, atol=1e-12)


def test_sh_field_and_masked_field_are_scattering_fields() -> None:
    """The interface train, render and extract use (fields.base.ScatteringField)."""
    from shsas_core.neural.fields import ScatteringField
    from shsas_core.neural.fields.occupancy import MaskedField

    field = SHField(FieldConfig(sh_degree=2))
    assert isinstance(field, ScatteringField)
    assert (field.device, field.dtype, field.config) == (torch.device("cpu"), torch.float32, field.cfg)
    masked = MaskedField(field, occupancy=None)  # the interface only: occupancy is not consulted
    assert isinstance(masked, ScatteringField) and masked.config is field.cfg
    masked.set_active_degree(0)  # reaches the wrapped field
    assert field._degree_hook is not None
    masked.set_active_degree(None)
    assert field._degree_hook is None
    assert not isinstance(torch.nn.Linear(2, 2), ScatteringField)


def test_level_window_is_barfs_cosine_window() -> None:
    from shsas_core.neural.fields.field import level_window

    w = level_window(4, 2, 2.25)
    want = [1.0, 1.0, (1 - math.cos(0.25 * math.pi)) / 2, 0.0]
    torch.testing.assert_close(w, torch.tensor(want, dtype=torch.float64).repeat_interleave(2))
    assert torch.equal(level_window(4, 1, 4.0), torch.ones(4, dtype=torch.float64))
    assert torch.equal(level_window(4, 1, 0.0), torch.zeros(4, dtype=torch.float64))


@pytest.mark.parametrize("fast", [False, True])
def test_active_levels_weight_the_encoding_in_every_output(fast: bool) -> None:
    """With levels switched off, the field equals a brute-force MLP of the encoding with those
    levels' features scaled, normals included (the fast path scales the Jacobian); None restores
    it exactly."""
    from shsas_core.neural.fields.field import level_window

    eager, field = _pair(2)
    f = field if fast else eager
    x, d = _inside(60), _dirs(60)
    full = f(x, d)
    f.set_active_levels(2.5)
    part = f(x, d)
    w = level_window(ENC.n_levels, ENC.n_features, 2.5)
    ref = f._mlp(f.encoding(f._unit(x)[0]) * w)
    torch.testing.assert_close(part["dc"].real, ref[:, 0] * (1 / math.sqrt(4 * math.pi)), rtol=0, atol=1e-12)
    assert not torch.allclose(part["density"], full["density"])
    # the normal is the gradient of the weighted field: compare with autograd of its density
    xg = x.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(f.density(xg).sum(), xg)
    torch.testing.assert_close(part["normals"], -torch.nn.functional.normalize(g, dim=1), rtol=0, atol=1e-8)
    f.set_active_levels(None)
    back = f(x, d)
    for k in ("density", "scattering", "normals"):
        assert torch.equal(back[k], full[k]), k
    f.set_active_levels(float(ENC.n_levels))
    assert f._level_weights is None
