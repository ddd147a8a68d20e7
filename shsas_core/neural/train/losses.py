"""The composite loss of one iteration: the rendered batch, the data term and the priors.

``L = λ1 L_ToF + λ2 L_sparse + λ3 TV(ρ) + λ4 TV(|σ|) + λ5 TV(∠σ) + λ6 L_ang`` (the terms are
defined in :mod:`shsas_core.neural.train`), and the learnable global scale ``A`` with its
closed-form start.
"""

from __future__ import annotations

import math

import torch

from shsas_core.neural.fields.sh import angular_roughness
from shsas_core.neural.render.renderer import PingGeometry, render_samples
from shsas_core.neural.render.sampling import cone_directions
from shsas_core.neural.train.config import TrainConfig
from shsas_core.neural.train.data import (
    TrainingData,
    iteration_generator,
    sample_batch,
    sample_psf_batch,
)

#: Random valid samples per iteration at which the TV priors and the angular prior look at the field.
REGULARISER_POINTS = 4096


class Amplitude(torch.nn.Module):
    """The global real scale ``A = exp(log_amplitude)`` between the field's output and the data."""

    def __init__(self) -> None:
        super().__init__()
        self.log_amplitude = torch.nn.Parameter(torch.zeros((), dtype=torch.float64))

    def forward(self) -> torch.Tensor:
        return torch.exp(self.log_amplitude)


def convolve_psf(signal: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """``out[k] = Σ_j psf[j] signal[k + 2h - j]`` over the bins where the kernel fits ("valid").

    Args:
        signal: (B, R) complex rendered impulse response on contiguous bins.
        psf: (2h + 1,) complex kernel, psf[h] at lag 0.
    Returns:
        (B, R - 2h) complex: what the deconvolved data would show at bins h .. R - h - 1.
    """
    taps = psf.numel()
    win = signal.unfold(-1, taps, 1)  # (B, R - 2h, taps): win[k, i] = signal[k + i]
    return win @ psf.flip(0).to(signal.dtype)


def render_batch(field, amp_mod, geom: PingGeometry, radii, cfg: TrainConfig, gen, create_graph=True):
    rcfg = cfg.render_config()
    dirs, omega = cone_directions(geom.axis, geom.half_angle, rcfg.num_rays, gen, jitter=True)
    return render_samples(field, geom, radii, dirs, omega, rcfg, amp_mod().to(radii.dtype), create_graph)


def regularisers(field, out: dict, geom: PingGeometry, cfg: TrainConfig, gen: torch.Generator,
                  tv_delta: float) -> dict[str, torch.Tensor]:
    valid = out["valid"]
    dens = out["density"]
    terms: dict[str, torch.Tensor] = {}
    nvalid = valid.sum().clamp_min(1)
    terms["sparsity"] = dens.sum() / nvalid
    w = cfg.weights
    if not w.any_sampled:
        return terms
    flat = torch.nonzero(valid.reshape(-1), as_tuple=False)[:, 0]
    if flat.numel() == 0:
        zero = dens.sum() * 0
        return terms | {"tv_density": zero, "tv_scatter": zero, "tv_phase": zero, "angular": zero}
    perm = torch.randperm(flat.numel(), generator=gen)[:REGULARISER_POINTS].to(flat.device)
    sel = flat[perm]
    x = out["x"].reshape(-1, 3)[sel]
    if w.angular > 0:
        terms["angular"] = relative_angular_roughness(field.coefficients(x))
    if not w.any_tv:
        return terms
    delta = torch.randn(sel.numel(), 3, generator=gen, dtype=torch.float64).to(x.device, x.dtype)
    delta = tv_delta * delta / delta.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    rx = geom.rx[:, None, None, :].expand(out["x"].shape).reshape(-1, 3)[sel]
    xd = x + delta
    look = xd - rx
    look = look / look.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    od = field(xd, look, with_normals=False)
    rho0, rho1 = dens.reshape(-1)[sel], od["density"]
    s0, s1 = out["scattering"].reshape(-1)[sel], od["scattering"]
    terms["tv_density"] = (rho0 - rho1).abs().mean()
    a0, a1 = s0.abs(), s1.abs()
    terms["tv_scatter"] = (a0 - a1).abs().mean()
    u0 = s0 / (a0 + 1e-12)
    u1 = s1 / (a1 + 1e-12)
    terms["tv_phase"] = (u0 - u1).abs().mean()
    return terms


def relative_angular_roughness(coeffs: torch.Tensor) -> torch.Tensor:
    """The angular prior λ6 weighs: ``Σ_p Σ_lm l(l+1) |c_lm(p)|² / Σ_p |c_00(p)|²``.

    The sphere's Dirichlet energy of the scattering (:func:`~shsas_core.neural.fields.sh.angular_roughness`)
    summed over the sample points, over their isotropic energy. The ratio is unitless (the
    field's scale is the learned amplitude's business) and weights points by their energy, so
    empty space neither dominates nor counts. The denominator is a constant of the step
    (detached): the prior shrinks the directional terms, it does not reward a brighter DC term.

    Args:
        coeffs: (P, (L+1)^2) complex SH coefficients at P points.
    Returns:
        () real >= 0; 0 when L = 0.
    """
    dc = coeffs[:, 0]
    energy = (dc.real.pow(2) + dc.imag.pow(2)).sum().detach()
    return angular_roughness(coeffs).sum() / energy.clamp_min(torch.finfo(energy.dtype).tiny)


def predict(field, amp_mod: Amplitude, data: TrainingData, survey, cfg: TrainConfig, gen: torch.Generator, device,
            dtype, psf: torch.Tensor | None, create_graph: bool = True):
    """Render one batch: (renderer outputs, ping geometry, predicted samples A·ŝ (B, K), measured
    samples (B, K))."""
    if psf is None:
        _pings, geom, radii, target = sample_batch(data, survey, gen, cfg, device, dtype)
        out = render_batch(field, amp_mod, geom, radii, cfg, gen, create_graph)
        return out, geom, out["signal"].to(target.dtype), target
    half = (psf.numel() - 1) // 2
    _pings, geom, radii, target = sample_psf_batch(data, survey, gen, cfg, half, device, dtype)
    out = render_batch(field, amp_mod, geom, radii, cfg, gen, create_graph)
    return out, geom, convolve_psf(out["signal"].to(target.dtype), psf), target


def iteration_loss(field, amp_mod: Amplitude, data: TrainingData, survey, cfg: TrainConfig, it: int, device, dtype,
                   tv_delta: float, psf: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite loss and data term of iteration ``it`` (every draw seeded by ``(seed, it)``)."""
    gen = iteration_generator(cfg.seed, it)
    out, geom, pred, target = predict(field, amp_mod, data, survey, cfg, gen, device, dtype, psf)
    data_loss = (pred - target).abs().pow(2).mean() / data.energy
    w = cfg.weights
    loss = w.tof * data_loss
    if w.sparsity > 0 or w.any_sampled:
        reg = regularisers(field, out, geom, cfg, gen, tv_delta)
        loss = loss + w.sparsity * reg["sparsity"]
        if w.angular > 0:
            loss = loss + w.angular * reg["angular"]
        if w.any_tv:
            loss = (loss + w.tv_density * reg["tv_density"] + w.tv_scatter * reg["tv_scatter"]
                    + w.tv_phase * reg["tv_phase"])
    return loss, data_loss


def init_amplitude(field, amp_mod: Amplitude, data: TrainingData, survey, cfg: TrainConfig, device, dtype,
                   psf: torch.Tensor | None = None, batches: int = 8) -> None:
    """Closed-form start for A: ‖s‖ / ‖ŝ‖ summed over ``batches`` seeded batches (streams
    1..batches of iteration 0), so one unusual view does not set the scale for all."""
    num = den = 0.0
    for j in range(batches):
        gen = iteration_generator(cfg.seed, 0, stream=1 + j)
        with torch.enable_grad():
            _out, _geom, pred, target = predict(field, amp_mod, data, survey, cfg, gen, device, dtype, psf,
                                                create_graph=False)
        num += float(target.abs().pow(2).sum())
        den += float((pred.detach() / amp_mod().detach().to(pred.real.dtype)).abs().pow(2).sum())
    num, den = math.sqrt(num), math.sqrt(den)
    if den > 0 and num > 0 and math.isfinite(num / den):
        with torch.no_grad():
            amp_mod.log_amplitude.fill_(math.log(num / den))
