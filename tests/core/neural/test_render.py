"""Renderer: ellipsoidal sampling, beam-cone rays, transmittance, forward model, transients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox, Survey, SurveyMeta, default_pulse
from shsas_core.neural.fields.field import safe_normalize
from shsas_core.neural.render import (
    RenderConfig,
    area_jacobian,
    cone_directions,
    cone_half_angles,
    intersect_focal,
    intersect_quadric,
    ping_geometry,
    points_on_rays,
    render_pings,
    render_samples,
    render_transients,
    sample_bins,
    signal_errors,
    transmittance,
    transmittance_cumprod,
)
from shsas_core.neural.render.renderer import PingGeometry, windowed_normals
from tests.helpers.analytic_field import ShellField

D = torch.float64


def _geometry(b=4, m=64, seed=0, bistatic=True):
    g = torch.Generator().manual_seed(seed)
    tx = torch.randn(b, 3, generator=g, dtype=D)
    rx = tx + (0.3 * torch.randn(b, 3, generator=g, dtype=D) if bistatic else 0.0)
    dirs = torch.randn(b, m, 3, generator=g, dtype=D)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    return tx, rx, dirs


@pytest.mark.parametrize("bistatic", [True, False])
@pytest.mark.parametrize("fn", [intersect_focal, intersect_quadric])
def test_points_lie_on_their_ellipsoids(fn, bistatic):
    tx, rx, dirs = _geometry(bistatic=bistatic)
    d = (tx - rx).norm(dim=-1)
    radii = d[:, None] + torch.linspace(1e-3, 3.0, 17, dtype=D)[None, :]
    dist, valid = fn(tx, rx, dirs, radii)
    assert valid.all()
    x = points_on_rays(tx, dirs, dist)
    path = (x - tx[:, None, None]).norm(dim=-1) + (x - rx[:, None, None]).norm(dim=-1)
    rel = ((path - radii[..., None]).abs() / radii[..., None]).max()
    assert rel < 1e-6
    assert (dist > 0).all()
    # samples along each ray are ordered like the radii
    assert (dist[:, 1:] >= dist[:, :-1]).all()


def test_focal_and_quadric_roots_agree_and_degenerate_bins_are_skipped():
    tx, rx, dirs = _geometry(b=3, m=32, seed=1)
    d = (tx - rx).norm(dim=-1)
    radii = torch.cat([0.5 * d[:, None], d[:, None] + torch.linspace(0.01, 2, 9, dtype=D)], dim=1)
    l1, v1 = intersect_focal(tx, rx, dirs, radii)
    l2, v2 = intersect_quadric(tx, rx, dirs, radii)
    assert torch.equal(v1, v2)
    assert not v1[:, 0].any()  # a <= d/2: no surface
    assert torch.allclose(l1, l2, rtol=1e-9, atol=1e-12)


def test_rays_stay_inside_the_cone_and_are_stratified():
    g = torch.Generator().manual_seed(3)
    axis = torch.randn(5, 3, dtype=D, generator=g)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    half = torch.tensor([0.05, 0.3, 1.0, 2.0, math.pi], dtype=D)
    dirs, omega = cone_directions(axis, half, 200, g)
    assert torch.allclose(dirs.norm(dim=-1), torch.ones(5, 200, dtype=D))
    ang = torch.arccos((dirs * axis[:, None]).sum(-1).clamp(-1, 1))
    assert (ang <= half[:, None] + 1e-12).all()
    assert torch.allclose(omega, 2 * math.pi * (1 - torch.cos(half)))
    # exactly one ray per equal-solid-angle stratum of cos(theta)
    cos_a = torch.cos(half)[:, None]
    stratum = torch.floor((1 - (dirs * axis[:, None]).sum(-1)) / (1 - cos_a) * 200).clamp(max=199)
    for row in stratum:
        assert sorted(row.long().tolist()) == list(range(200))


def test_cone_covers_the_scene_box_and_honours_beamwidth():
    box = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))
    tx = np.array([[0.8, 0.0, 0.3], [0.0, -0.9, 0.1]])
    axis = np.asarray(box.center)[None] - tx
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    half = cone_half_angles(tx, axis, box.min, box.max, None)
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (0, 0.2)])
    for n in range(2):
        v = corners - tx[n]
        ang = np.arccos(v @ axis[n] / np.linalg.norm(v, axis=1))
        assert ang.max() <= half[n] and half[n] < ang.max() * 1.001
    assert np.allclose(cone_half_angles(tx, axis, box.min, box.max, 30.0), math.radians(15))


def test_transmittance_matches_a_brute_force_loop():
    g = torch.Generator().manual_seed(4)
    rho = torch.rand(2, 7, 5, generator=g, dtype=D) * 30
    dist = torch.cumsum(torch.rand(2, 7, 5, generator=g, dtype=D) * 0.05, dim=1)
    ref = torch.ones_like(rho)
    for b in range(2):
        for m in range(5):
            for i in range(7):
                t = 1.0
                for j in range(i):
                    t *= math.exp(-float(rho[b, j, m]) * abs(float(dist[b, j + 1, m] - dist[b, j, m])))
                ref[b, i, m] = t
    assert torch.allclose(transmittance(rho, dist, two_way=False), ref, rtol=1e-12)
    assert torch.allclose(transmittance(rho, dist, two_way=True), ref**2, rtol=1e-12)
    assert torch.allclose(transmittance_cumprod(rho, dist, two_way=True), ref**2, rtol=1e-12)


def test_area_jacobian_integrates_to_the_spheroid_area():
    tx = torch.tensor([[0.0, 0.0, 0.0]], dtype=D)
    rx = torch.tensor([[0.3, 0.1, -0.2]], dtype=D)
    d = float((tx - rx).norm())
    r = 1.2
    axis = torch.tensor([[0.0, 0.0, 1.0]], dtype=D)
    m = 40000
    dirs, omega = cone_directions(axis, torch.tensor([math.pi], dtype=D), m, None, jitter=False)
    dist, valid = intersect_focal(tx, rx, dirs, torch.tensor([[r]], dtype=D))
    assert valid.all()
    x = points_on_rays(tx, dirs, dist)
    rt = (x - tx).norm(dim=-1)
    rr = (x - rx).norm(dim=-1)
    area = float((omega / m) * (area_jacobian(tx, rx, x, dirs) * rt * rr).sum())
    a, b = r / 2, math.sqrt(r * r / 4 - d * d / 4)
    e = math.sqrt(1 - b * b / (a * a))
    exact = 2 * math.pi * b * b * (1 + a / (b * e) * math.asin(e))
    assert abs(area - exact) / exact < 2e-3
    mono = area_jacobian(tx, tx, x, dirs)
    assert torch.allclose(mono, torch.ones_like(mono))


def test_sample_bins_distinct_sorted_valid_and_distributed_as_pdf():
    g = torch.Generator().manual_seed(5)
    w = torch.rand(3, 50, generator=g, dtype=D) ** 4
    valid = torch.zeros(3, 50, dtype=torch.bool)
    valid[:, 10:40] = True
    idx, pdf = sample_bins(w, valid, 12, 0.2, g)
    assert idx.shape == (3, 12)
    assert (idx[:, 1:] > idx[:, :-1]).all()
    assert valid.gather(1, idx).all()
    # single draws follow p = 0.8 |s|/sum + 0.2 uniform over valid bins
    p = torch.where(valid, w, 0.0)
    p = 0.8 * p / p.sum(1, keepdim=True) + 0.2 * valid / valid.sum(1, keepdim=True)
    assert torch.allclose(pdf, p.gather(1, idx))
    counts = torch.zeros(50, dtype=D)
    for _ in range(4000):
        i, _ = sample_bins(w[:1], valid[:1], 1, 0.2, g)
        counts[i[0, 0]] += 1
    assert (counts / 4000 - p[0]).abs().max() < 0.03
    with pytest.raises(ShsasError):
        sample_bins(w, torch.zeros_like(valid), 4, 0.1, g)


def _geom(tx, rx, center):
    axis = center - tx
    axis = axis / axis.norm(dim=-1, keepdim=True)
    return PingGeometry(tx, rx, axis, torch.full((tx.shape[0],), 0.15, dtype=tx.dtype))


@pytest.mark.parametrize("window", [1, 5])  # the paper's normals and the default window
def test_renderer_gradcheck_float64(window):
    field = ShellField(width=0.02)
    tx = torch.tensor([[0.6, 0.0, 0.15], [0.0, 0.5, 0.05]], dtype=D)
    rx = tx + torch.tensor([[0.01, 0.0, -0.04], [0.0, 0.02, 0.03]], dtype=D)
    geom = _geom(tx, rx, field.center.detach()[None])
    dist_c = (field.center.detach() - tx).norm(dim=-1)
    radii = 2 * dist_c[:, None] + torch.linspace(-0.12, -0.06, 4, dtype=D)[None, :]
    g = torch.Generator().manual_seed(0)
    cfg = RenderConfig(num_rays=12, normal_window=window)
    from shsas_core.neural.render import cone_directions as cd

    dirs, omega = cd(geom.axis, geom.half_angle, 12, g)
    params = [field.center, field.radius, field.log_amp, field.beta]

    def fn(center, radius, log_amp, beta):
        with torch.no_grad():
            for p, v in zip(params, (center, radius, log_amp, beta), strict=True):
                p.copy_(v)
        field.center, field.radius, field.log_amp, field.beta = center, radius, log_amp, beta
        return render_samples(field, geom, radii, dirs, omega, cfg, create_graph=True)["signal"]

    inputs = tuple(p.detach().clone().requires_grad_(True) for p in params)
    # plain tensors replace the Parameters for the check (functional use of the module)
    for name in ("center", "radius", "log_amp", "beta"):
        delattr(field, name)
    out = fn(*inputs)
    assert out.abs().max() > 0  # the check is not vacuous
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_fast_and_eager_renderer_agree():
    field = ShellField()
    tx = torch.tensor([[0.7, 0.1, 0.2]], dtype=D)
    rx = torch.tensor([[0.71, 0.1, 0.16]], dtype=D)
    geom = _geom(tx, rx, field.center.detach()[None])
    dc = float((field.center.detach() - tx).norm())
    radii = torch.linspace(2 * dc - 0.15, 2 * dc + 0.1, 40, dtype=D)[None]
    outs = [render_pings(field, geom, radii, RenderConfig(num_rays=256, backend=b),
                         torch.Generator().manual_seed(1))["signal"] for b in ("fast", "reference")]
    assert outs[0].abs().max() > 0
    assert torch.allclose(outs[0], outs[1], rtol=1e-7, atol=1e-10)


def test_occluded_back_of_shell_is_dark_and_echo_sits_at_the_front_surface():
    # dense shell: the front surface echoes, the back is shadowed by the two-way transmittance
    field = ShellField(center=(0.0, 0.0, 0.0), radius=0.05, width=0.004, amp=2000.0, beta=0.0)
    tx = torch.tensor([[0.6, 0.0, 0.0]], dtype=D)
    geom = _geom(tx, tx.clone(), field.center.detach()[None])
    radii = torch.linspace(2 * 0.53, 2 * 0.67, 300, dtype=D)[None]
    s = render_pings(field, geom, radii, RenderConfig(num_rays=2000), torch.Generator().manual_seed(2))["signal"][0]
    mag = s.abs()
    front = 2 * (0.6 - 0.05)
    back = 2 * (0.6 + 0.05)
    r_peak = float(radii[0, mag.argmax()])
    # a dense shell reflects from its outer skirt: the peak is within ~2.5 widths (one way)
    # before the nominal front surface, never behind it
    assert front - 2 * 2.5 * 0.004 < r_peak <= front + 0.002
    back_energy = mag[(radii[0] > back - 0.01) & (radii[0] < back + 0.01)].max()
    assert back_energy < 1e-3 * mag.max()
    # with zero density (no occlusion) and no Lambertian term the back surface does echo
    clear = ShellField(center=(0.0, 0.0, 0.0), radius=0.05, width=0.004, amp=2000.0, beta=0.0, zeta=0.0)
    free = render_pings(clear, geom, radii, RenderConfig(num_rays=2000, lambertian=False),
                        torch.Generator().manual_seed(2))["signal"][0].abs()
    assert free[(radii[0] > back - 0.01) & (radii[0] < back + 0.01)].max() > 0.1 * free.max()


def _survey(n=3, t=700):
    meta = SurveyMeta(platform="test", scene_box=SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2)))
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tx = np.stack([0.6 * np.cos(ang), 0.6 * np.sin(ang), np.full(n, 0.12)], 1)
    rx = tx + np.array([0.0, 0.0, -0.03])
    return Survey(tx=tx, rx=rx, samples=np.zeros((n, t), np.float32), t0=np.full(n, 2.5e-3),
                  meta=meta, pulse=default_pulse(meta))


def test_render_transients_equals_training_render_on_the_same_rays():
    survey = _survey()
    field = ShellField(center=(0.0, 0.0, 0.1), radius=0.04, width=0.006, amp=50.0)
    cfg = RenderConfig(num_rays=300)
    full = render_transients(field, survey, [0, 2], cfg, amplitude=2.0, seed=7, bins_per_chunk=50)
    assert full.shape == (2, 700) and full.dtype == np.complex64
    assert np.abs(full).max() > 0
    # same rays (seed 7, first ping) through render_samples on a subset of bins
    geom = ping_geometry(survey, [0], "cpu", D)
    gen = torch.Generator().manual_seed(7)
    dirs, omega = cone_directions(geom.axis, geom.half_angle, 300, gen)
    r_all = survey.meta.sound_speed * (survey.t0[0] + np.arange(700) / survey.meta.fs)
    nz = np.nonzero(full[0])[0]
    radii = torch.as_tensor(r_all[nz], dtype=D)[None]
    direct = render_samples(field, geom, radii, dirs, omega, cfg, 2.0, create_graph=False)["signal"][0]
    assert np.allclose(full[0, nz], direct.detach().numpy(), rtol=1e-4, atol=1e-6 * np.abs(full).max())
    # outside the scene's range window the transient is exactly 0
    box = survey.meta.scene_box
    r_lo = np.linalg.norm(survey.tx[0] - np.clip(survey.tx[0], box.min, box.max)) * 2
    assert np.all(full[0, r_all < r_lo - 0.05] == 0)


def test_signal_errors_layout_and_values():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 20)) + 1j * rng.standard_normal((3, 20))
    b = rng.standard_normal((3, 20)) + 1j * rng.standard_normal((3, 20))
    e = signal_errors(a, b)
    assert set(e) == {"l1_real", "l1_imag", "l1_abs", "mse_real", "mse_imag", "mse_abs"}
    assert e["l1_real"] == pytest.approx(np.mean(np.abs(a.real - b.real)))
    assert e["mse_abs"] == pytest.approx(np.mean((np.abs(a) - np.abs(b)) ** 2))
    assert signal_errors(a, a)["mse_imag"] == 0.0
    with pytest.raises(ShsasError):
        signal_errors(a, b[:2])


def test_baseband_surveys_render_in_their_own_convention():
    import dataclasses

    pas = _survey()
    meta = pas.meta.model_copy(update={"signal_kind": "baseband", "carrier_hz": 20e3})
    bb = dataclasses.replace(pas, meta=meta, samples=pas.samples.astype(np.complex64))
    field = ShellField(center=(0.0, 0.0, 0.1), radius=0.04, width=0.006, amp=50.0)
    cfg = RenderConfig(num_rays=64)
    a = render_transients(field, pas, [1], cfg, seed=3)
    b = render_transients(field, bb, [1], cfg, seed=3)
    t = pas.t0[1] + np.arange(pas.num_samples) / pas.meta.fs
    assert np.abs(a).max() > 0
    assert np.allclose(b[0], a[0] * np.exp(-2j * np.pi * 20e3 * t), rtol=1e-4, atol=1e-6 * np.abs(a).max())


@pytest.mark.parametrize("window", [1, 5])  # the paper's normals and the default window
def test_renderer_gradcheck_with_a_tiny_shfield_float64(window):
    """Gradients of the rendered bins w.r.t. the SH field's output layer (through scattering,
    density/transmittance and the normals of the Lambertian term) match finite differences."""
    from shsas_core.neural.fields import HashEncodingConfig, SHField
    from shsas_core.neural.fields.config import FieldConfig

    box = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))
    torch.manual_seed(0)
    enc = HashEncodingConfig(n_levels=2, log2_table_size=6, base_resolution=4, finest_resolution=8)
    f = SHField(FieldConfig(sh_degree=1, encoding=enc, hidden=8, scene_box=box)).double()
    with torch.no_grad():
        f.encoding.table.uniform_(-0.3, 0.3)
    tx = torch.tensor([[0.5, 0.05, 0.12]], dtype=D)
    rx = tx + torch.tensor([[0.01, 0.0, -0.03]], dtype=D)
    geom = _geom(tx, rx, torch.tensor([[0.0, 0.0, 0.1]], dtype=D))
    radii = torch.tensor([[0.9, 0.95, 1.0, 1.05]], dtype=D)
    dirs, omega = cone_directions(geom.axis, geom.half_angle, 6, torch.Generator().manual_seed(0))
    last = f.linears[-1]
    inp = last.weight.detach().clone().requires_grad_(True)
    del last.weight  # use a plain tensor as the weight, so gradcheck can perturb it

    def fn(weight):
        last.weight = weight
        return render_samples(f, geom, radii, dirs, omega, RenderConfig(num_rays=6, normal_window=window),
                             create_graph=True)["signal"]

    assert fn(inp).abs().min() > 0
    assert torch.autograd.gradcheck(fn, (inp,), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_windowed_normals_match_a_loop() -> None:
    gen = torch.Generator().manual_seed(3)
    grad = torch.randn(2, 9, 5, 3, generator=gen, dtype=D)
    grad[0, 4, 1] = 0.0
    grad[1, :3, 2] = 0.0  # a sum of zeros: the normal is 0, not NaN
    for w in (1, 2, 4, 9, 12):
        want = torch.zeros_like(grad)
        for b in range(2):
            for k in range(9):
                for m in range(5):
                    total = sum(grad[b, j, m] for j in range(max(0, k - w + 1), k + 1))
                    norm = float(total.norm())
                    want[b, k, m] = -total / norm if norm > 0 else 0.0
        torch.testing.assert_close(windowed_normals(grad, w), want, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(windowed_normals(grad, 1), -safe_normalize(grad))
    with pytest.raises(ShsasError, match="window"):
        windowed_normals(grad, 0)


def test_windowed_normals_gradcheck() -> None:
    grad = torch.randn(1, 6, 2, 3, generator=torch.Generator().manual_seed(4), dtype=D, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: windowed_normals(t, 3), (grad,))


def test_normal_window_lights_the_ridge_of_a_thin_shell() -> None:
    # One ray from a monostatic ping straight through a thin Gaussian shell. Past the ridge the
    # gradient points back at the sonar, so the field's own normal faces away and the Lambertian
    # term is 0: the paper's renderer lights only the near flank, so a sheet renders off its peak
    # and the fit builds a double sheet. A window's summed gradient is the density's rise over the
    # window, so the lit part reaches half a window past the ridge and is centred on it.
    field = ShellField(center=(0.0, 0.0, 0.0), radius=0.05, width=0.004, amp=1.0, beta=0.0)
    tx = torch.tensor([[0.6, 0.0, 0.0]], dtype=D)
    geom = _geom(tx, tx.clone(), field.center.detach()[None])
    dirs = torch.tensor([[[-1.0, 0.0, 0.0]]], dtype=D)
    ridge = 0.55  # one-way distance from the sonar to the shell's ridge along the ray
    step = 0.0015
    one_way = ridge + step * torch.arange(-6, 4, dtype=D)  # sample 6 is on the ridge
    radii = (2 * one_way)[None]
    omega = torch.ones(1, dtype=D)

    def lit(window: int) -> torch.Tensor:
        cfg = RenderConfig(num_rays=1, normal_window=window)
        return render_samples(field, geom, radii, dirs, omega, cfg, create_graph=False)["lambertian"][0, :, 0]

    g1, g4 = lit(1), lit(4)
    torch.testing.assert_close(g1[:6], torch.ones(6, dtype=D))  # the near flank faces the sonar
    assert torch.all(g1[7:] == 0)
    torch.testing.assert_close(g4[:8], torch.ones(8, dtype=D))  # ... and now one step past the ridge
    assert torch.all(g4[8:] == 0)  # the far flank stays dark


def test_windowed_normal_at_a_shell_ridge_points_outward_by_finite_differences() -> None:
    # An oblique ray (not through the centre) crosses a thin Gaussian shell; sample 6 lies exactly
    # on its ridge, where ∇|σ_DC| = 0. The paper's normal (W = 1) is then the zero vector and the
    # Lambertian term 0. A window of 5 sums the gradients of the rising flank before the ridge:
    # the normal is non-zero, points out of the shell and towards the sonar. The reference is
    # central finite differences of the density, independent of autograd and of windowed_normals.
    field = ShellField(center=(0.0, 0.0, 0.0), radius=0.05, width=0.004, amp=1.0, beta=0.0)
    center = field.center.detach()
    ridge_point = 0.05 * torch.tensor([math.cos(0.5) * math.cos(0.3), math.sin(0.5) * math.cos(0.3),
                                       math.sin(0.3)], dtype=D)
    tx = torch.tensor([[0.6, 0.05, 0.02]], dtype=D)
    u = (ridge_point - tx[0]) / (ridge_point - tx[0]).norm()
    geom = _geom(tx, tx.clone(), center[None])
    dirs = u[None, None]
    step = 0.0015  # m along the ray, about a fifth of the shell's ±2σ width
    one_way = (ridge_point - tx[0]).norm() + step * torch.arange(-6, 4, dtype=D)
    radii = (2 * one_way)[None]
    window, ridge = 5, 6

    def lit(w: int) -> dict[str, torch.Tensor]:
        cfg = RenderConfig(num_rays=1, normal_window=w)
        return render_samples(field, geom, radii, dirs, torch.ones(1, dtype=D), cfg, create_graph=False)

    x = lit(window)["x"][0, :, 0]  # (K, 3) the samples
    torch.testing.assert_close(x[ridge], ridge_point, rtol=0, atol=1e-12)

    # reference: the density's central differences (h = 1e-6 m) at the window's samples, summed
    h = 1e-6
    eye = torch.eye(3, dtype=D) * h
    with torch.no_grad():
        fd = (field.dc_abs(x[:, None] + eye) - field.dc_abs(x[:, None] - eye)) / (2 * h)  # (K, 3) 1/m²
    total = fd[ridge - window + 1: ridge + 1].sum(0)
    want = -total / total.norm()

    paper, windowed = lit(1), lit(window)
    own = windowed["gradient"][0, :, 0]  # the field's own gradients, what the paper's normal is made of
    torch.testing.assert_close(own, fd, rtol=0, atol=1e-6 * fd.norm(dim=-1).max())
    assert own[ridge].norm() < 1e-9 * own[ridge - 2].norm()  # it vanishes on the ridge
    assert torch.all(paper["lambertian"][0, ridge + 1:, 0] == 0)  # and past it the paper's term is dark
    n = windowed_normals(windowed["gradient"], window)[0, ridge, 0]
    torch.testing.assert_close(n, want, rtol=0, atol=1e-6)
    outward = (x[ridge] - center) / (x[ridge] - center).norm()
    assert float(n @ outward) > 0.5  # out of the shell, not along the ray only
    assert float(n @ -u) > 0  # towards the sonar, so the ridge is lit
    torch.testing.assert_close(windowed["lambertian"][0, ridge, 0], (want @ -u).clamp_min(0), rtol=0, atol=1e-6)
    assert torch.all(windowed["lambertian"][0, ridge + 1: ridge + 3, 0] > 0.5)  # lit past the ridge too


def test_render_transients_applies_the_normal_window_across_chunks() -> None:
    survey = _survey()
    field = ShellField(center=(0.0, 0.0, 0.1), radius=0.04, width=0.006, amp=50.0)
    win = RenderConfig(num_rays=300, normal_window=4)
    one = render_transients(field, survey, [0, 1], win, seed=7, bins_per_chunk=1000)
    chunked = render_transients(field, survey, [0, 1], win, seed=7, bins_per_chunk=5)
    assert np.abs(one).max() > 0
    np.testing.assert_allclose(chunked, one, rtol=1e-5, atol=1e-6 * np.abs(one).max())
    plain = render_transients(field, survey, [0, 1], RenderConfig(num_rays=300, normal_window=1), seed=7,
                              bins_per_chunk=1000)
    assert np.abs(plain - one).max() > 0.01 * np.abs(one).max()  # the window changes the render
