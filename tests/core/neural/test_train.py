"""Trainer: loss, checkpoints, exact resume, cancellation, regularisers, CLI; sphere fit (slow)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import torch

from shsas_core.common.errors import Cancelled, ShsasError
from shsas_core.neural.fields import HashEncodingConfig, SHField
from shsas_core.neural.fields.config import FieldConfig
from shsas_core.neural.render import RenderConfig, render_transients, signal_errors
from shsas_core.neural.train import (
    LossWeights,
    TrainConfig,
    coarse_start_levels,
    convolve_psf,
    fit,
    load_checkpoint,
    relative_angular_roughness,
)
from tests.helpers.sphere_data import density_concentration, sphere_survey


@pytest.fixture(autouse=True)
def _one_thread():
    """Tiny batches: one thread beats two on a shared 2-core machine (and avoids oversubscription)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


SMALL = HashEncodingConfig(n_levels=8, log2_table_size=13, base_resolution=8, finest_resolution=128)
TINY = HashEncodingConfig(n_levels=3, n_features=2, log2_table_size=9, base_resolution=4, finest_resolution=16)


@pytest.fixture(scope="module")
def small():
    return sphere_survey(n_pings=8, samples=200, n_points=1500)


def _field(survey, degree=1, seed=0, encoding=None):
    torch.manual_seed(seed)
    return SHField(FieldConfig(sh_degree=degree, encoding=encoding or TINY, hidden=16,
                               scene_box=survey.meta.scene_box))


def _cfg(**kw):
    base = dict(iters=10, lr=1e-2, num_bins=8, num_rays=16, pings_per_batch=2, device="cpu", seed=3,
                checkpoint_every=4)
    return TrainConfig(**(base | kw))


def test_interrupted_then_resumed_equals_uninterrupted(small, tmp_path):
    survey, sig = small
    ref = fit(_field(survey), survey, sig, _cfg())
    calls = {"n": 0}

    def stop_after_6() -> bool:
        calls["n"] += 1
        return calls["n"] > 6

    field = _field(survey)
    with pytest.raises(Cancelled):
        fit(field, survey, sig, _cfg(), should_stop=stop_after_6, checkpoint_dir=tmp_path)
    ck = load_checkpoint(tmp_path / "checkpoint.pt")
    assert ck["iteration"] == 6 and len(ck["loss_history"]) == 6
    # the global RNGs are restored too; disturb them to prove the draws do not depend on them
    torch.manual_seed(12345)
    np.random.seed(1)
    res = fit(_field(survey, seed=99), survey, sig, _cfg(), checkpoint_dir=tmp_path)
    assert res.start_iteration == 6 and res.iterations == 10
    assert np.allclose(res.loss_history, ref.loss_history, rtol=0, atol=1e-6)
    assert len(set(np.round(ref.loss_history, 6))) > 5  # a real, changing curve


def test_a_checkpoint_resumes_under_another_field_backend(small, tmp_path):
    # the backends compute the same maths: the fingerprint leaves `backend` out, the rest stays
    survey, sig = small
    calls = {"n": 0}

    def stop_after_4() -> bool:
        calls["n"] += 1
        return calls["n"] > 4

    with pytest.raises(Cancelled):
        fit(_field(survey), survey, sig, _cfg(), should_stop=stop_after_4, checkpoint_dir=tmp_path)
    torch.manual_seed(0)
    other = SHField(FieldConfig(sh_degree=1, encoding=TINY, hidden=16, scene_box=survey.meta.scene_box,
                                backend="reference"))
    assert fit(other, survey, sig, _cfg(), checkpoint_dir=tmp_path).start_iteration == 4
    wider = SHField(FieldConfig(sh_degree=1, encoding=TINY, hidden=17, scene_box=survey.meta.scene_box))
    with pytest.raises(ShsasError, match="different configuration"):
        fit(wider, survey, sig, _cfg(), checkpoint_dir=tmp_path)


def test_a_checkpoint_naming_retired_options_at_their_remaining_behaviour_resumes(small, tmp_path):
    """Checkpoints from before the trainer lost reg_start, tv_points, learn_amplitude and
    progressive_sh_every name them in their fingerprint: at the one behaviour left they resume, at
    any other value they were another training and are refused."""
    survey, sig = small
    cfg = {"average_last": None}  # extending a run moves its average's start; beside the point here
    fit(_field(survey), survey, sig, _cfg(iters=4, **cfg), checkpoint_dir=tmp_path)
    path = tmp_path / "checkpoint.pt"
    ck = load_checkpoint(path)
    old = {"reg_start": 0, "tv_points": 4096, "learn_amplitude": True, "progressive_sh_every": None}
    ck["fingerprint"]["train"].update(old)
    torch.save(ck, path)
    assert fit(_field(survey), survey, sig, _cfg(iters=6, **cfg), checkpoint_dir=tmp_path).start_iteration == 4
    ck = load_checkpoint(path)
    ck["fingerprint"]["train"].update(old | {"reg_start": 2})
    torch.save(ck, path)
    with pytest.raises(ShsasError, match="different configuration"):
        fit(_field(survey), survey, sig, _cfg(iters=8, **cfg), checkpoint_dir=tmp_path)


def test_progress_metrics_and_checkpoint_contents(small, tmp_path):
    survey, sig = small
    seen = []
    res = fit(_field(survey), survey, sig, _cfg(iters=5), progress=lambda f, s, m: seen.append((f, s, dict(m))),
              checkpoint_dir=tmp_path, stage="fit:test")
    assert [round(f, 3) for f, _, _ in seen] == [0.2, 0.4, 0.6, 0.8, 1.0]
    assert all(s == "fit:test" and {"loss", "data_loss", "it/s"} <= set(m) for _, s, m in seen)
    assert res.iters_per_s > 0 and res.amplitude > 0
    ck = load_checkpoint(res.checkpoint_path)
    assert set(ck) >= {"field", "optimizer", "rng", "iteration", "loss_history", "amplitude"}
    assert set(ck["rng"]) >= {"torch", "numpy", "python"}
    assert ck["iteration"] == 5
    assert not list(tmp_path.glob("*.tmp*"))  # atomic write left no temporary
    # a finished run re-run with more iterations continues; a different config is refused
    more = fit(_field(survey), survey, sig, _cfg(iters=7), checkpoint_dir=tmp_path)
    assert more.start_iteration == 5 and len(more.loss_history) == 7
    with pytest.raises(ShsasError, match="different configuration"):
        fit(_field(survey), survey, sig, _cfg(iters=8, num_rays=32), checkpoint_dir=tmp_path)


def test_bad_signals_are_refused(small):
    survey, sig = small
    with pytest.raises(ShsasError, match="shape"):
        fit(_field(survey), survey, sig[:, :10], _cfg(iters=1))
    with pytest.raises(ShsasError, match="complex"):
        fit(_field(survey), survey, sig.real, _cfg(iters=1))
    with pytest.raises(ShsasError, match="zero"):
        fit(_field(survey), survey, np.zeros_like(sig), _cfg(iters=1))


def _box_points(survey, n=4000, seed=0):
    """(n, 3) float32 points uniform in the survey's scene box, m."""
    box = survey.meta.scene_box
    u = torch.rand(n, 3, generator=torch.Generator().manual_seed(seed))
    return u * torch.tensor(box.size, dtype=torch.float32) + torch.tensor(box.min, dtype=torch.float32)


def test_sparsity_weight_lowers_density(small):
    """λ2 > 0 lowers the density."""
    survey, sig = small
    pts = _box_points(survey)
    means = []
    for w in (0.0, 1000.0):
        f = _field(survey)
        fit(f, survey, sig, _cfg(iters=30, weights=LossWeights(sparsity=w)))
        with torch.no_grad():
            means.append(float(f.density(pts).mean()))
    assert means[1] < 0.5 * means[0]


def test_relative_angular_roughness_against_a_loop_and_its_gradient():
    """Ratio of sums by a plain loop; the gradient is the numerator's over a constant denominator
    (gradcheck of the same expression with the denominator passed in as a number)."""
    g = torch.Generator().manual_seed(5)
    c = torch.complex(torch.randn(6, 16, dtype=torch.float64, generator=g),
                      torch.randn(6, 16, dtype=torch.float64, generator=g))
    num = sum(l * (l + 1) * abs(complex(c[p, l * l + l + m])) ** 2
              for p in range(6) for l in range(4) for m in range(-l, l + 1))  # noqa: E741
    den = sum(abs(complex(c[p, 0])) ** 2 for p in range(6))
    assert float(relative_angular_roughness(c)) == pytest.approx(num / den, rel=1e-12)
    x = c.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda z: _numerator_over(z, den), (x,))
    (grad,) = torch.autograd.grad(relative_angular_roughness(x), x)
    (ref,) = torch.autograd.grad(_numerator_over(x, den), x)
    torch.testing.assert_close(grad, ref)  # no gradient through the DC energy


def _numerator_over(c, den):
    l = torch.tensor([l for l in range(4) for _ in range(2 * l + 1)], dtype=torch.float64)  # noqa: E741
    return ((c.real**2 + c.imag**2) * l * (l + 1)).sum() / den


def test_angular_prior_shrinks_the_directional_terms_and_is_void_at_degree_0(small):
    """λ6 > 0 lowers the fitted field's angular roughness relative to its DC energy; at L = 0
    there is nothing to shrink, so the losses are those of λ6 = 0 to the bit."""
    survey, sig = small
    pts = _box_points(survey)
    rough = []
    for w in (0.0, 10.0):
        f = _field(survey, degree=2)
        fit(f, survey, sig, _cfg(iters=30, lr=3e-3, weights=LossWeights(angular=w)))
        with torch.no_grad():
            rough.append(float(relative_angular_roughness(f.coefficients(pts))))
    assert rough[1] < 0.5 * rough[0]
    losses = [fit(_field(survey, degree=0), survey, sig, _cfg(iters=5, weights=LossWeights(angular=w))).loss_history
              for w in (0.0, 10.0)]
    assert losses[0] == losses[1]


def test_each_tv_term_alone_smooths_its_quantity(small):
    survey, sig = small
    box = survey.meta.scene_box
    g = torch.Generator().manual_seed(1)
    lo, size = torch.tensor(box.min, dtype=torch.float32), torch.tensor(box.size, dtype=torch.float32)
    x = torch.rand(3000, 3, generator=g) * size + lo
    dx = 0.004 * torch.nn.functional.normalize(torch.randn(3000, 3, generator=g), dim=-1)
    look = torch.nn.functional.normalize(torch.randn(3000, 3, generator=g), dim=-1)

    def tv_of(f):
        with torch.no_grad():
            a, b = f(x, look, with_normals=False), f(x + dx, look, with_normals=False)
        return {"tv_density": float((a["density"] - b["density"]).abs().mean()),
                "tv_scatter": float((a["scattering"].abs() - b["scattering"].abs()).abs().mean()),
                "tv_phase": float((torch.exp(1j * a["scattering"].angle())
                                   - torch.exp(1j * b["scattering"].angle())).abs().mean())}

    def rough():
        f = _field(survey)
        with torch.no_grad():  # start rough so there is variation to smooth
            f.encoding.table.uniform_(-0.5, 0.5, generator=torch.Generator().manual_seed(2))
            f.linears[-1].weight.mul_(30.0)
        return f

    before = tv_of(rough())
    for name in ("tv_density", "tv_scatter", "tv_phase"):
        f = rough()
        cfg = _cfg(iters=20, lr=3e-3, num_rays=32, tv_delta=0.004, weights=LossWeights(tof=0.0, **{name: 1.0}))
        res = fit(f, survey, sig, cfg)
        assert res.loss_history[-1] < res.loss_history[0]  # the loss is the TV term alone
        assert tv_of(f)[name] < 0.7 * before[name], name


def test_progressive_sh_masks_higher_degrees(small):
    survey, _ = small
    f = _field(survey, degree=2)
    x = torch.tensor([[0.01, 0.02, 0.1]]).repeat(5, 1)
    dirs = torch.nn.functional.normalize(torch.randn(5, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    with torch.no_grad():
        torch.nn.init.normal_(f.linears[-1].weight)
        full = f(x, dirs, with_normals=False)["scattering"]
        f.set_active_degree(0)
        iso = f(x, dirs, with_normals=False)["scattering"]
        f.set_active_degree(None)
        back = f(x, dirs, with_normals=False)["scattering"]
    assert not torch.allclose(full, full[:1].expand(5))  # direction-dependent with L=2
    assert torch.allclose(iso, iso[:1].expand(5))  # isotropic with degree 0 active
    assert torch.equal(back, full)


def test_cli_fit_writes_outputs_and_resumes(small, tmp_path):
    """`shsas fit` takes the spec's options and signals (the spec's deconvolution, not the stored
    extras), keeps the field and resumes a longer run from its checkpoint."""
    from shsas_core.cli import main
    from shsas_core.formats.hdf5 import write_survey

    survey, sig = small
    survey.extras["deconvolved"] = sig
    path = write_survey(survey, tmp_path / "s.h5")
    out = tmp_path / "run"
    # --init none: the warm start's fixed 300 steps of 32k points would be most of this test
    argv = ["fit", str(path), "--method", "reed", "--iters", "3", "--device", "cpu", "--out", str(out),
            "--bins", "4", "--rays", "8", "--grid", "8", "--no-progress", "--init", "none"]
    assert main(argv) == 0
    hist = json.loads((out / "loss_history.json").read_text())
    assert hist["sh_degree"] == 0 and len(hist["loss_history"]) == 3
    assert hist["signals"] == "wiener deconvolution" and hist["spec"]["num_bins"] == 4
    saved = torch.load(out / "field.pt", weights_only=False)
    assert saved["field_config"]["sh_degree"] == 0 and "state_dict" in saved
    assert (out / "checkpoint.pt").exists() and (out / "reed_volume.npy").exists()
    argv[argv.index("--iters") + 1] = "5"
    assert main(argv) == 0
    hist2 = json.loads((out / "loss_history.json").read_text())
    assert hist2["start_iteration"] == 3 and hist2["loss_history"][:3] == hist["loss_history"]
    assert main(["fit", str(tmp_path / "missing.h5"), "--out", str(out)]) == 2
    with pytest.raises(SystemExit) as refused:  # argparse: a method that fits no field
        main(["fit", str(path), "--method", "backprojection", "--out", str(out)])
    assert refused.value.code == 2


@pytest.mark.slow
def test_training_on_a_sphere_fits_the_data_and_finds_the_surface():
    """Isotropic field (L = 0) on 48 ideal incoherent echo profiles of a 5 cm sphere: the data loss
    falls >= 10x from its value at initialisation (mean of the first 10 vs the last 20 iterations)
    and the mean density within 1 cm of the true surface is >= 2.5x the mean density in the free
    space outside (see ``density_concentration``)."""
    survey, sig = sphere_survey(coherent=False)
    torch.manual_seed(0)
    enc = HashEncodingConfig(n_levels=8, log2_table_size=13, base_resolution=8, finest_resolution=128)
    f = SHField(FieldConfig(sh_degree=0, encoding=enc, scene_box=survey.meta.scene_box))
    assert density_concentration(f, (0.0, 0.0, 0.09), 0.05, survey.meta.scene_box) < 1.1  # flat start
    # the paper's normal: this is the impulse model, whose sampled bins are not contiguous along a
    # ray, so a window of them is no finite difference (the window is meant for forward psf)
    cfg = TrainConfig(iters=1500, lr=3e-3, num_bins=32, num_rays=128, device="cpu", seed=0,
                      render=RenderConfig(normal_window=1))
    res = fit(f, survey, sig, cfg)
    h = np.asarray(res.data_loss_history)
    assert h[:10].mean() >= 10 * h[-20:].mean()
    assert density_concentration(f, (0.0, 0.0, 0.09), 0.05, survey.meta.scene_box) >= 2.5
    # rendering whole pings beats predicting zeros
    pred = render_transients(f, survey, [0, 5], RenderConfig(num_rays=256, normal_window=1), amplitude=res.amplitude)
    err = signal_errors(pred, sig[[0, 5]])
    assert err["mse_abs"] < signal_errors(np.zeros_like(pred), sig[[0, 5]])["mse_abs"]


@pytest.mark.gpu
def test_fit_and_render_on_cuda(small, tmp_path):
    survey, sig = small
    f = _field(survey)
    res = fit(f, survey, sig, _cfg(iters=4, device="cuda"), checkpoint_dir=tmp_path)
    assert next(f.parameters()).is_cuda and np.all(np.isfinite(res.loss_history))
    pred = render_transients(f, survey, [0], RenderConfig(num_rays=32), amplitude=res.amplitude)
    assert pred.shape == (1, survey.num_samples) and np.isfinite(pred).all()


def test_envelope_target_fits_the_magnitude_of_s_pd(small):
    """target="envelope" trains on |s_PD|: the same run as coherent training on |s_PD| itself, blind
    to the phase of the signals, and different from coherent training on s_PD."""
    survey, sig = small
    env = fit(_field(survey), survey, sig, _cfg(target="envelope"))
    on_abs = fit(_field(survey), survey, np.abs(sig).astype(np.complex128), _cfg())
    assert np.allclose(env.loss_history, on_abs.loss_history, rtol=0, atol=1e-6)
    assert env.signal_energy == pytest.approx(on_abs.signal_energy, rel=1e-6)
    phase = np.exp(1j * np.random.default_rng(0).uniform(0, 2 * np.pi, sig.shape))
    rotated = fit(_field(survey), survey, sig * phase, _cfg(target="envelope"))
    assert np.allclose(env.loss_history, rotated.loss_history, rtol=1e-4, atol=0)  # float32 rounding of |s|
    coherent = fit(_field(survey), survey, sig, _cfg())
    assert not np.allclose(env.loss_history, coherent.loss_history, rtol=1e-2, atol=0)
    with pytest.raises(ValueError):
        _cfg(target="power")


def test_lr_decay_reaches_lr_final_and_resumes_exactly(small, tmp_path):
    from shsas_core.neural.train import scheduled_lr

    cfg = _cfg(lr=1e-2, lr_final=1e-4)
    lrs = [scheduled_lr(cfg, i) for i in range(cfg.iters)]
    assert lrs[0] == pytest.approx(1e-2) and lrs[-1] == pytest.approx(1e-4)
    assert np.allclose(np.diff(np.log(lrs)), np.log(1e-2) / (cfg.iters - 1))  # exponential
    survey, sig = small
    ref = fit(_field(survey), survey, sig, cfg)
    const = fit(_field(survey), survey, sig, _cfg(lr=1e-2))
    assert not np.allclose(ref.loss_history, const.loss_history, rtol=0, atol=1e-6)
    with pytest.raises(Cancelled):
        n = iter(range(100))
        fit(_field(survey), survey, sig, cfg, should_stop=lambda: next(n) >= 5, checkpoint_dir=tmp_path)
    res = fit(_field(survey, seed=7), survey, sig, cfg, checkpoint_dir=tmp_path)
    assert res.start_iteration == 5
    assert np.allclose(res.loss_history, ref.loss_history, rtol=0, atol=1e-6)
    # the schedule depends on iters, so a decaying run cannot be extended by resuming
    with pytest.raises(ShsasError, match="different configuration"):
        fit(_field(survey), survey, sig, _cfg(lr=1e-2, lr_final=1e-4, iters=20), checkpoint_dir=tmp_path)


def test_evaluate_data_loss_against_a_direct_sum(small):
    from shsas_core.data.geometry import two_way_range_bounds
    from shsas_core.neural.render.sampling import bin_radii
    from shsas_core.neural.train import evaluate_data_loss

    survey, sig = small
    f = _field(survey, degree=1)
    pings = [0, 3, 5]
    own = render_transients(f, survey, pings, RenderConfig(num_rays=32))
    full = np.zeros_like(sig)
    full[pings] = own
    # the field's own rendering: perfect with the best scale, exactly 1 at twice the scale
    assert evaluate_data_loss(f, survey, full, pings, num_rays=32) < 1e-10
    assert evaluate_data_loss(f, survey, full, pings, num_rays=32, amplitude=2.0) == pytest.approx(1.0, rel=1e-6)
    # any signals: the weighted sum written out bin by bin
    got = evaluate_data_loss(f, survey, sig, pings, num_rays=32, amplitude=0.5, uniform_fraction=0.2)
    num = den = 0.0
    box = survey.meta.scene_box
    for row, n in enumerate(pings):
        r = bin_radii(survey.t0[[n]], survey.meta.fs, survey.meta.sound_speed, survey.num_samples)[0]
        lo, hi = two_way_range_bounds(survey.tx[[n]], survey.rx[[n]], box)
        base = np.linalg.norm(survey.tx[n] - survey.rx[n])
        ks = [k for k in range(survey.num_samples) if lo[0] <= r[k] <= hi[0] and r[k] > base]
        tot = sum(abs(complex(sig[n, k])) for k in ks)
        for k in ks:
            s = complex(sig[n, k])
            p = 0.8 * abs(s) / tot + 0.2 / len(ks)
            num += p * abs(0.5 * complex(own[row, k]) - s) ** 2
            den += p * abs(s) ** 2
    assert got == pytest.approx(num / den, rel=1e-6)
    env = evaluate_data_loss(f, survey, sig, pings, target="envelope", num_rays=32)
    assert 0 <= env < 1.0  # a positive field correlates with |s| better than zeros do


def test_diverged_training_stops_with_a_clear_error_and_saves_nothing(small, tmp_path):
    survey, sig = small
    f = _field(survey)
    with torch.no_grad():
        f.encoding.table.fill_(float("nan"))
    with pytest.raises(ShsasError, match="loss became nan at iteration 0.*lower learning rate"):
        fit(f, survey, sig, _cfg(iters=4), checkpoint_dir=tmp_path)
    assert not (tmp_path / "checkpoint.pt").exists()  # no NaN state is ever written


def _second_layer_alive(field, box, n: int = 4000) -> tuple[int, float]:
    """Units of the last hidden layer active anywhere on random points, and std/mean of the density."""
    g = torch.Generator().manual_seed(1)
    lo, hi = torch.tensor(box.min), torch.tensor(box.max)
    x = lo + (hi - lo) * torch.rand(n, 3, generator=g)
    with torch.no_grad():
        h = field.encoding((x - field.box_min) / field.box_size)
        for lin in field.linears[:-1]:
            h = torch.relu(lin(h))
        d = field.density(x)
    return int((h > 0).any(0).sum()), float(d.std() / d.mean())


@pytest.mark.slow
def test_sh_sas_at_lr_3e_3_does_not_collapse_to_a_constant_field(shared):
    """The simulated bunny, seed 1, L = 3 at lr 3e-3 (the demo's setting). With plain directional
    outputs (directional_scale = 1) every unit of the second hidden layer died within 50 steps,
    which left a constant field: zero normals, zero signal, no gradient (F1 0 in Table 1). The
    default directional_scale keeps the layer alive and the density varying."""
    from shsas_core.signal.deconv import deconvolve
    from shsas_core.simulation.simulate import simulate_shape
    from shsas_core.simulation.trajectory import TrajectoryConfig

    survey = simulate_shape(str(shared / "data" / "meshes" / "bunny.obj"), snr_db=20.0, seed=1,
                            trajectory=TrajectoryConfig(heights=4, angles=90, subset_seed=1))
    spd = deconvolve(survey)
    torch.manual_seed(1)
    f = SHField(FieldConfig(sh_degree=3, scene_box=survey.meta.scene_box))
    # the paper's normal: the impulse model from the empty field, as when the collapse was found
    # (with the default window this run keeps 3 units alive, not 4)
    fit(f, survey, spd, TrainConfig(iters=150, lr=3e-3, num_bins=32, num_rays=128, device="cpu", seed=1,
                                    target="envelope", render=RenderConfig(normal_window=1)))
    alive, spread = _second_layer_alive(f, survey.meta.scene_box)
    assert alive >= 4, alive
    assert spread > 1e-3, spread


def test_convolve_psf_is_numpy_valid_convolution_and_differentiable():
    rng = np.random.default_rng(0)
    sig = rng.normal(size=(3, 40)) + 1j * rng.normal(size=(3, 40))
    psf = rng.normal(size=17) + 1j * rng.normal(size=17)
    got = convolve_psf(torch.from_numpy(sig), torch.from_numpy(psf)).numpy()
    ref = np.stack([np.convolve(row, psf, "valid") for row in sig])
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
    x = torch.from_numpy(sig[:, :12]).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: convolve_psf(v, torch.from_numpy(psf[:5])), (x,))


def test_psf_forward_model_explains_band_limited_echoes_better(small):
    """On echoes made with a known band-limited kernel, the same field and budget reach a lower
    data loss when the renderer's impulse response is convolved with that kernel."""
    survey, sig = small
    meta = survey.meta
    lags = np.arange(-8, 9) / meta.fs
    kernel = np.exp(2j * np.pi * meta.pulse.f_center * lags) * np.sinc(meta.pulse.bandwidth * lags)
    losses = {}
    for name, psf in (("impulse", None), ("psf", kernel)):
        field = _field(survey, degree=0)
        cfg = _cfg(iters=80, num_rays=64, num_bins=32, psf_window=32, lr=1e-2)
        r = fit(field, survey, sig, cfg, psf=psf)
        losses[name] = float(np.mean(r.data_loss_history[-20:]))
    assert losses["psf"] < losses["impulse"], losses


def test_tail_average_is_the_mean_of_the_last_iterates_and_resumes_exactly(small, tmp_path):
    survey, sig = small
    snapshots: list[list[torch.Tensor]] = []
    field = _field(survey)

    def record(*_args) -> None:  # called after every optimiser step: the iterate
        snapshots.append([p.detach().clone() for p in field.parameters()])

    fit(field, survey, sig, _cfg(average_last=0.4), progress=record)
    assert len(snapshots) == 10
    expected = [torch.stack(ps).mean(0) for ps in zip(*snapshots[-4:], strict=True)]  # 0.4 x 10 iterates
    for got, want in zip(field.parameters(), expected, strict=True):
        assert torch.allclose(got.detach(), want, rtol=1e-5, atol=1e-7)
    assert any(not torch.allclose(g.detach(), last) for g, last in zip(field.parameters(), snapshots[-1], strict=True))

    # interrupted inside the averaged tail (at 8) and resumed: the same average
    with pytest.raises(Cancelled):
        n = iter(range(100))
        fit(_field(survey), survey, sig, _cfg(average_last=0.4), should_stop=lambda: next(n) >= 8,
            checkpoint_dir=tmp_path)
    resumed = _field(survey, seed=5)
    fit(resumed, survey, sig, _cfg(average_last=0.4), checkpoint_dir=tmp_path)
    for a, b in zip(resumed.parameters(), field.parameters(), strict=True):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-7)
    # extended so that its average would have begun before the checkpoint: refused, naming the fix
    with pytest.raises(ShsasError, match=r"past iteration 7 .* fix: 17 iterations or more"):
        fit(_field(survey), survey, sig, _cfg(average_last=0.4, iters=12), checkpoint_dir=tmp_path)
    # extended far enough: the average starts afresh over the new run's last 40 % (iterates 13-20)
    snapshots.clear()
    longer = _field(survey, seed=6)
    res = fit(longer, survey, sig, _cfg(average_last=0.4, iters=20), checkpoint_dir=tmp_path,
              progress=lambda *_a: snapshots.append([p.detach().clone() for p in longer.parameters()]))
    assert res.start_iteration == 10 and len(snapshots) == 10
    expected = [torch.stack(ps).mean(0) for ps in zip(*snapshots[-8:], strict=True)]
    for got, want in zip(longer.parameters(), expected, strict=True):
        assert torch.allclose(got.detach(), want, rtol=1e-5, atol=1e-7)


def test_active_levels_ramp_from_the_coarse_start_to_every_level():
    from shsas_core.neural.fields.encoding import PRESETS
    from shsas_core.neural.train import COARSE_TO_FINE_START_RESOLUTION, active_levels

    enc = PRESETS["cpu"]
    start = sum(r <= COARSE_TO_FINE_START_RESOLUTION for r in enc.resolutions())
    assert coarse_start_levels(enc) == start == 8
    a = [active_levels(enc, 0.25, it, 2000) for it in range(0, 2000, 10)]
    assert a[0] == start and all(x <= y for x, y in itertools.pairwise(a))
    assert active_levels(enc, 0.25, 250, 2000) == pytest.approx(start + (enc.n_levels - start) / 2)
    assert active_levels(enc, 0.25, 500, 2000) == enc.n_levels == active_levels(enc, 0.25, 1999, 2000)


def test_coarse_to_fine_goes_through_the_field_interface_and_resumes_exactly(small, tmp_path):
    """fit raises the active levels each iteration through set_active_levels and leaves every
    level on at the end; an interrupted run resumes to the same field; a plain module (no hash
    levels) trains as before."""
    survey, sig = small
    # two levels at or under the coarse start's resolution, two finer ones
    enc = HashEncodingConfig(n_levels=4, n_features=2, log2_table_size=8, base_resolution=64, finest_resolution=512)
    assert coarse_start_levels(enc) == 2
    f = _field(survey, encoding=enc)
    seen = []
    real = f.set_active_levels
    f.set_active_levels = lambda a: (seen.append(a), real(a))[1]
    cfg = _cfg(iters=8, coarse_to_fine=0.5)
    whole = fit(f, survey, sig, cfg)
    n = f.config.encoding.n_levels
    assert seen[0] < seen[3] < n and seen[4] == n and seen[-1] is None and f._level_weights is None
    calls = {"n": 0}

    def stop_after_3() -> bool:
        calls["n"] += 1
        return calls["n"] > 3

    with pytest.raises(Cancelled):
        fit(_field(survey, encoding=enc), survey, sig, cfg, checkpoint_dir=tmp_path, should_stop=stop_after_3)
    again = fit(_field(survey, seed=99, encoding=enc), survey, sig, cfg, checkpoint_dir=tmp_path)
    assert again.start_iteration == 3
    assert np.allclose(again.loss_history, whole.loss_history, rtol=0, atol=1e-6)
    class Plain(torch.nn.Module):  # only forward: not a ScatteringField
        def __init__(self) -> None:
            super().__init__()
            self.inner = _field(survey, encoding=enc)

        def forward(self, *a, **k):
            return self.inner(*a, **k)

    off = fit(Plain(), survey, sig, _cfg(iters=3, coarse_to_fine=None)).loss_history
    assert fit(Plain(), survey, sig, _cfg(iters=3, coarse_to_fine=0.5)).loss_history == off
