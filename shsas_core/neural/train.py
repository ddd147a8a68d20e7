"""Analysis-by-synthesis training of a scattering field on pulse-deconvolved pings (paper §4.4).

Each iteration picks ``pings_per_batch`` training pings, importance-samples ``num_bins`` range bins
per ping (∝ |s_PD| plus a uniform share), renders them with ``num_rays`` TX rays
(:mod:`shsas_core.neural.render`), and takes one Adam step (lr 1e-3) on the composite loss

    L = λ1 L_ToF + λ2 L_sparse + λ3 TV(ρ) + λ4 TV(|σ|) + λ5 TV(∠σ) + λ6 L_ang

* ``L_ToF = mean_k |A ŝ_k - s_k|^2 / E`` — mean squared complex error (real² + imag²) of the
  rendered bins, divided by the constant ``E``, the expected |s|² of a bin drawn by the sampler
  (averaged over the training pings); predicting zeros scores 1.0 in expectation, so the value
  reads as a relative residual.
* ``L_sparse = mean ρ(x)`` over the valid samples (L1: ρ >= 0).
* TV terms compare the field at ``R`` random valid samples ``x`` and at ``x + δ``, ``δ`` a random
  direction of length ``tv_delta`` (default: 1/128 of the scene-box diagonal):
  ``TV(ρ) = mean |ρ(x) - ρ(x+δ)|``, ``TV(|σ|) = mean ||σ(x)| - |σ(x+δ)||``,
  ``TV(∠σ) = mean |e^{i∠σ(x)} - e^{i∠σ(x+δ)}|`` (chord distance on the unit circle: ≈ |Δφ|
  for small differences, no 2π wrap, bounded gradient).
* ``L_ang = Σ_x Σ_lm l(l+1)|c_lm(x)|² / Σ_x |c_00(x)|²`` over the same ``R`` samples: the
  scattering lobe's Dirichlet energy on the sphere relative to its isotropic energy
  (:func:`relative_angular_roughness`), a prior towards smooth, low-degree lobes (not in the paper).

Data term (``TrainConfig.target``): ``"coherent"`` (default, the paper) fits the complex s_PD;
``"envelope"`` replaces every target ``s_k`` by ``|s_k|`` (real, non-negative) before anything
else, so ``E`` and the bin sampler see ``|s|`` too. Envelope is a deviation from the paper for
CPU budgets: the paper's renderer assumes ideal pulse deconvolution, while Wiener s_PD keeps the
band-pass pulse PSF (carrier under an envelope), which a coherent fit can only explain with a
complex σ oscillating along range (long GPU runs); |s_PD| has no carrier, so a density shell on
the surface explains it within a few hundred iterations (docs/neural.md).

``A = exp(log_amplitude)`` is one learnable real scale, initialised in closed form before the
first step as ``‖s‖ / ‖ŝ‖`` over 8 seeded batches, so the field does not have to grow its output by
orders of magnitude to meet the data's units. Default weights follow the paper's simulated
setting (regularisers off: λ1 = 1, λ2..λ6 = 0); :data:`AIRSAS_WEIGHTS` keeps the ratios of the
public AirSAS configuration.

Determinism and resume: every random draw of iteration ``i`` comes from generators seeded with
``(seed, i)``, so the draws do not depend on history; a checkpoint (field, amplitude, optimiser,
iteration, loss history and the global torch/numpy/python RNG states, written atomically)
therefore resumes to the same loss curve as an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import json
import math
import random
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator

from shsas_core.common.atomic import atomic_path
from shsas_core.common.device import resolve_device
from shsas_core.common.errors import Cancelled, ShsasError
from shsas_core.common.heap import heap_cache
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, no_progress
from shsas_core.neural.fields.base import ScatteringField, device_dtype
from shsas_core.neural.fields.occupancy import OccupancyGrid, within
from shsas_core.neural.fields.sh import angular_roughness
from shsas_core.neural.render.renderer import (
    PingGeometry,
    RenderConfig,
    passband_factor,
    ping_geometry,
    render_samples,
)
from shsas_core.neural.render.sampling import (
    bin_radii,
    cone_directions,
    sample_bins,
    scene_range_window,
)
from shsas_core.spec.options import (
    AVERAGE_LAST,
    AVERAGE_LAST_HELP,
    COARSE_TO_FINE,
    COARSE_TO_FINE_HELP,
    COARSE_TO_FINE_START_RESOLUTION,
    ITERS,
    LR,
    LR_FINAL_HELP,
    NUM_BINS,
    NUM_RAYS,
    PINGS_PER_BATCH,
    SEED,
    TARGET,
    TARGET_HELP,
    UNIFORM_FRACTION,
    AverageLast,
    CoarseToFine,
    DeviceName,
    FinalLearningRate,
    Iters,
    LearningRate,
    NumBins,
    NumRays,
    PingsPerBatch,
    Seed,
    Target,
    UniformFraction,
)

CHECKPOINT_NAME = "checkpoint.pt"


class LossWeights(BaseModel):
    """λ1..λ5 of the composite loss (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    tof: float = Field(1.0, ge=0, description="λ1, ToF data term")
    # a weight like λ3..λ5, unbounded above; the job spec caps it at 100 for users (SparsityWeight)
    # and defaults it to 1 (the paper's simulated setting is this 0)
    sparsity: float = Field(0.0, ge=0, description="λ2, L1 of density")
    tv_density: float = Field(0.0, ge=0, description="λ3, TV of density")
    tv_scatter: float = Field(0.0, ge=0, description="λ4, TV of |σ|")
    tv_phase: float = Field(0.0, ge=0, description="λ5, TV of ∠σ")
    angular: float = Field(0.0, ge=0, description="λ6, angular roughness Σ l(l+1)|c_lm|² of the SH "
                           "coefficients relative to their DC energy (0 for L = 0)")

    @property
    def any_tv(self) -> bool:
        return self.tv_density > 0 or self.tv_scatter > 0 or self.tv_phase > 0

    @property
    def any_sampled(self) -> bool:
        """Whether a term needs the field at the regularisers' random sample points."""
        return self.any_tv or self.angular > 0


#: Ratios of the public AirSAS configuration of the paper (sparsity 1e1, smooth 5e1, phase 1e-1
#: relative to a data term that was a plain mean squared error); a starting point for real data.
AIRSAS_WEIGHTS = LossWeights(tof=1.0, sparsity=1e-3, tv_density=0.0, tv_scatter=5e-3, tv_phase=1e-5)


#: The sampling options TrainConfig owns and hands to its RenderConfig.
_SAMPLING = frozenset({"num_bins", "num_rays", "uniform_fraction"})


class TrainConfig(BaseModel):
    """Training options. Defaults run on a 2-core CPU; the paper used 200 bins x ~4800 rays."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # the options a job spec also carries: bounds and defaults from shsas_core.spec.options
    iters: Iters = ITERS
    lr: LearningRate = LR
    lr_final: FinalLearningRate | None = Field(None, description=LR_FINAL_HELP)
    num_bins: NumBins = NUM_BINS
    num_rays: NumRays = NUM_RAYS
    pings_per_batch: PingsPerBatch = PINGS_PER_BATCH
    uniform_fraction: UniformFraction = UNIFORM_FRACTION
    target: Target = Field(TARGET, description=TARGET_HELP)
    weights: LossWeights = LossWeights()
    tv_delta: float | None = Field(None, gt=0, description="TV offset length, m; None: box diagonal/128")
    tv_points: int = Field(4096, ge=1, description="samples per iteration used by the TV terms "
                            "and the angular prior")
    reg_start: int = Field(0, ge=0, description="iteration from which λ2..λ6 apply")
    learn_amplitude: bool = Field(True, description="learn the global scale A (else fixed at its init)")
    psf_window: int = Field(64, ge=1, le=4096, description="with a point-spread kernel (fit's psf): "
                            "contiguous target bins per ping and iteration (replaces num_bins)")
    seed: Seed = SEED
    average_last: AverageLast | None = Field(AVERAGE_LAST, description=AVERAGE_LAST_HELP)
    coarse_to_fine: CoarseToFine | None = Field(COARSE_TO_FINE, description=COARSE_TO_FINE_HELP)
    progressive_sh_every: int | None = Field(
        None, ge=1, description="raise the active SH degree by one every N iterations (starts at 0)")
    checkpoint_every: int = Field(500, ge=1)
    heap_cache: bool = Field(True, description="keep freed CPU buffers in the heap during the loop "
                             "(glibc; no per-iteration page faults, see shsas_core.common.heap)")
    device: DeviceName = "auto"
    render: RenderConfig = Field(default_factory=RenderConfig, description="the renderer's other options; "
                                 "its num_bins, num_rays and uniform_fraction are the fields above")

    @model_validator(mode="after")
    def _one_sampling_setting(self) -> TrainConfig:
        # render_config() takes these from the fields above: a value set in render as well
        # would be dropped without a word, so it is an error instead
        twice = sorted(self.render.model_fields_set & _SAMPLING)
        if twice:
            raise ValueError(f"render.{', render.'.join(twice)}: set these on TrainConfig itself")
        return self

    def render_config(self) -> RenderConfig:
        return self.render.model_copy(update={"num_bins": self.num_bins, "num_rays": self.num_rays,
                                              "uniform_fraction": self.uniform_fraction})


@dataclasses.dataclass
class FitResult:
    """What :func:`fit` returns.

    Attributes:
        loss_history: total loss per iteration, from iteration 0 (resumed runs include the
            iterations before the resume).
        data_loss_history: the ToF term (relative, see module docstring) per iteration.
        iters_per_s: iterations per second of this call (excludes set-up).
        iterations: iterations completed in total. start_iteration: where this call started.
        amplitude: fitted global scale A (pass to ``render_transients``).
        signal_energy: ``E``, the mean |s|² used to normalise the data term.
        checkpoint_path: last checkpoint written, if any. elapsed_s: wall time of this call.
    """

    loss_history: list[float]
    data_loss_history: list[float]
    iters_per_s: float
    iterations: int
    start_iteration: int
    amplitude: float
    signal_energy: float
    checkpoint_path: str | None
    elapsed_s: float

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class _Amplitude(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.log_amplitude = torch.nn.Parameter(torch.zeros((), dtype=torch.float64))

    def forward(self) -> torch.Tensor:
        return torch.exp(self.log_amplitude)


@dataclasses.dataclass
class _Data:
    """Training signals and per-ping range axes on the CPU (moved per batch)."""

    signals: torch.Tensor  # (N, T) complex64
    magnitude: torch.Tensor  # (N, T) float32 |s|
    t0: np.ndarray  # (N,) s, first-sample times (radii are c (t0 + k / fs), made per batch)
    valid: torch.Tensor  # (N, T) bool, inside the scene's range window (and beyond the baseline)
    pings: np.ndarray  # (n_train,) indices of the training pings
    energy: float  # expected |s|^2 of a drawn bin (see _prepare)


def _window_mask(survey, pings: np.ndarray) -> np.ndarray:
    """(len(pings), T) bool: samples whose two-way path lies in the scene's range window and
    beyond the TX-RX baseline (the bins training may draw)."""
    radii = bin_radii(survey.t0[pings], survey.meta.fs, survey.meta.sound_speed, survey.num_samples)
    box = survey.meta.scene_box
    r_lo, r_hi = scene_range_window(survey.tx[pings], survey.rx[pings], box.min, box.max)
    base = np.linalg.norm(survey.tx[pings] - survey.rx[pings], axis=1)
    return (radii >= r_lo[:, None]) & (radii <= r_hi[:, None]) & (radii > base[:, None])


def _bin_weights(mag: np.ndarray, valid: np.ndarray, uniform_fraction: float) -> np.ndarray:
    """The bin sampler's pdf per ping, ``(1-u) |s| / Σ|s| + u / n_valid`` over the valid bins
    (uniform where a ping's valid bins are all zero): mag, valid (N, T) -> (N, T)."""
    n_valid = np.maximum(valid.sum(axis=1, keepdims=True), 1)
    w = np.where(valid, mag, 0.0)
    tot = w.sum(axis=1, keepdims=True)
    shape = np.where(tot > 0, w / np.where(tot > 0, tot, 1), valid / n_valid)
    return (1 - uniform_fraction) * shape + uniform_fraction * valid / n_valid


def _prepare(survey, signals: np.ndarray, ping_indices: Sequence[int] | None,
             uniform_fraction: float, target: str = "coherent") -> _Data:
    s = np.asarray(signals)
    if s.ndim != 2 or s.shape != (survey.num_pings, survey.num_samples):
        raise ShsasError(f"fit: signals must have shape (pings={survey.num_pings}, samples="
                         f"{survey.num_samples}), got {s.shape}")
    if not np.iscomplexobj(s):
        raise ShsasError("fit: signals must be complex (analytic or pulse-deconvolved s_PD)")
    if not np.all(np.isfinite(s)):
        raise ShsasError("fit: signals contain NaN or inf")
    factor = passband_factor(survey)
    if factor is not None:  # baseband survey: train on the analytic passband equivalent
        s = s * factor
    if target == "envelope":
        # |s_PD| as a real, non-negative complex target: the band-pass carrier is gone, so a
        # density shell on the surface can explain it without the field learning the pulse PSF
        s = np.abs(s).astype(np.complex128)
    valid = _window_mask(survey, np.arange(survey.num_pings))
    pings = (np.arange(survey.num_pings) if ping_indices is None
             else np.unique(np.asarray(ping_indices, dtype=np.int64)))
    if pings.size == 0 or pings.min() < 0 or pings.max() >= survey.num_pings:
        raise ShsasError(f"fit: ping_indices must be non-empty and within 0..{survey.num_pings - 1}")
    pings = pings[valid[pings].any(axis=1)]
    if pings.size == 0:
        raise ShsasError("fit: no training ping records any range bin inside the scene box "
                         "(fix: check t0, sensor positions and meta.scene_box)")
    # E = expected |s|^2 of one drawn bin under the sampling pdf, averaged over training pings,
    # so a zero prediction scores 1.0 in expectation
    mag = np.abs(s[pings]).astype(np.float64)
    p = _bin_weights(mag, valid[pings], uniform_fraction)
    energy = float(np.mean((p * mag**2).sum(axis=1)))
    if not energy > 0:
        raise ShsasError("fit: the signals are all zero inside the scene's range window")
    return _Data(torch.from_numpy(s.astype(np.complex64)), torch.from_numpy(np.abs(s).astype(np.float32)),
                 np.asarray(survey.t0, dtype=np.float64), torch.from_numpy(valid), pings, energy)


def _generator(seed: int, iteration: int, stream: int = 0) -> torch.Generator:
    # SeedSequence mixes (seed, iteration, stream) into well-separated 64-bit seeds
    s = np.random.SeedSequence([seed, iteration, stream]).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(s) & ((1 << 63) - 1))


def _pick_pings(data: _Data, cfg: TrainConfig, it_gen: torch.Generator) -> np.ndarray:
    """The iteration's training pings, sorted (the first draw from ``it_gen``)."""
    n_train = len(data.pings)
    pick = torch.randperm(n_train, generator=it_gen)[: min(cfg.pings_per_batch, n_train)].numpy()
    return np.sort(data.pings[pick])


def _bin_geometry(data: _Data, survey, pings: np.ndarray, bins: torch.Tensor, cfg: TrainConfig, device, dtype):
    """(ping geometry, two-way radii (B, K) of the sample indices ``bins``, m)."""
    meta = survey.meta
    r = meta.sound_speed * (data.t0[pings][:, None] + bins.numpy() / meta.fs)  # same formula as bin_radii
    radii = torch.as_tensor(r, dtype=dtype, device=device)
    return ping_geometry(survey, pings, device, dtype, cfg.render.beamwidth_deg), radii


def _batch(data: _Data, survey, it_gen: torch.Generator, cfg: TrainConfig, device, dtype):
    """Pings, bins and their targets of one iteration (all draws from ``it_gen``)."""
    pings = _pick_pings(data, cfg, it_gen)
    idx, _pdf = sample_bins(data.magnitude[pings], data.valid[pings], cfg.num_bins, cfg.uniform_fraction, it_gen)
    target = data.signals[torch.as_tensor(pings)[:, None], idx].to(device)
    geom, radii = _bin_geometry(data, survey, pings, idx, cfg, device, dtype)
    return pings, geom, radii, target


def _psf_batch(data: _Data, survey, it_gen: torch.Generator, cfg: TrainConfig, half: int, device, dtype):
    """One contiguous window of ``psf_window`` target bins per ping (its centre drawn by the bin
    sampler's pdf) and the ``2 half`` bins around it that the kernel reaches: the rendered bins.

    Returns pings, geometry, radii (B, W + 2 half) of the rendered bins, targets (B, W).
    """
    pings = _pick_pings(data, cfg, it_gen)
    valid = data.valid[pings]
    centre, _pdf = sample_bins(data.magnitude[pings], valid, 1, cfg.uniform_fraction, it_gen)
    n_t = valid.shape[1]
    w = min(cfg.psf_window, n_t)
    first = valid.to(torch.int64).argmax(dim=1)
    last = n_t - 1 - valid.flip(1).to(torch.int64).argmax(dim=1)
    start = (centre[:, 0] - w // 2).clamp(min=first, max=(last - w + 1).clamp_min(first)).clamp(0, n_t - w)
    cols = start[:, None] + torch.arange(w)[None, :]
    target = data.signals[torch.as_tensor(pings)[:, None], cols].to(device)
    rend = start[:, None] - half + torch.arange(w + 2 * half)[None, :]
    geom, radii = _bin_geometry(data, survey, pings, rend, cfg, device, dtype)
    return pings, geom, radii, target


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


def _render_batch(field, amp_mod, geom: PingGeometry, radii, cfg: TrainConfig, gen, create_graph=True):
    rcfg = cfg.render_config()
    dirs, omega = cone_directions(geom.axis, geom.half_angle, rcfg.num_rays, gen, jitter=True)
    return render_samples(field, geom, radii, dirs, omega, rcfg, amp_mod().to(radii.dtype), create_graph)


def _regularisers(field, out: dict, geom: PingGeometry, cfg: TrainConfig, gen: torch.Generator,
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
    perm = torch.randperm(flat.numel(), generator=gen)[: cfg.tv_points].to(flat.device)
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


def _predict(field, amp_mod: _Amplitude, data: _Data, survey, cfg: TrainConfig, gen: torch.Generator, device,
             dtype, psf: torch.Tensor | None, create_graph: bool = True):
    """Render one batch: (renderer outputs, ping geometry, predicted samples A·ŝ (B, K), measured
    samples (B, K))."""
    if psf is None:
        _pings, geom, radii, target = _batch(data, survey, gen, cfg, device, dtype)
        out = _render_batch(field, amp_mod, geom, radii, cfg, gen, create_graph)
        return out, geom, out["signal"].to(target.dtype), target
    half = (psf.numel() - 1) // 2
    _pings, geom, radii, target = _psf_batch(data, survey, gen, cfg, half, device, dtype)
    out = _render_batch(field, amp_mod, geom, radii, cfg, gen, create_graph)
    return out, geom, convolve_psf(out["signal"].to(target.dtype), psf), target


def _iteration_loss(field, amp_mod: _Amplitude, data: _Data, survey, cfg: TrainConfig, it: int, device, dtype,
                    tv_delta: float, psf: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite loss and data term of iteration ``it`` (every draw seeded by ``(seed, it)``)."""
    gen = _generator(cfg.seed, it)
    out, geom, pred, target = _predict(field, amp_mod, data, survey, cfg, gen, device, dtype, psf)
    data_loss = (pred - target).abs().pow(2).mean() / data.energy
    w = cfg.weights
    loss = w.tof * data_loss
    if it >= cfg.reg_start and (w.sparsity > 0 or w.any_sampled):
        reg = _regularisers(field, out, geom, cfg, gen, tv_delta)
        loss = loss + w.sparsity * reg["sparsity"]
        if w.angular > 0:
            loss = loss + w.angular * reg["angular"]
        if w.any_tv:
            loss = (loss + w.tv_density * reg["tv_density"] + w.tv_scatter * reg["tv_scatter"]
                    + w.tv_phase * reg["tv_phase"])
    return loss, data_loss


def _atomic_save(obj: Any, path: Path) -> None:
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def coarse_start_levels(encoding: Any) -> int:
    """Hash levels on at the start of a coarse-to-fine fit: those of resolution up to
    :data:`COARSE_TO_FINE_START_RESOLUTION` (at least one)."""
    return max(1, sum(r <= COARSE_TO_FINE_START_RESOLUTION for r in encoding.resolutions()))


def active_levels(encoding: Any, fraction: float, it: int, iters: int) -> float:
    """Active hash levels at iteration ``it`` of a coarse-to-fine fit: from
    :func:`coarse_start_levels` up to every level, linearly over the first ``fraction * iters``
    iterations (``SHField.set_active_levels``)."""
    start, n = coarse_start_levels(encoding), encoding.n_levels
    return start + (n - start) * min(1.0, it / max(1.0, fraction * iters))


def _fingerprint(cfg: TrainConfig, field: torch.nn.Module, data: _Data) -> dict[str, Any]:
    """What must match for a checkpoint to be resumed (iters may grow unless the lr decays over
    them; a weight average is checked by :func:`_resume_average`). Coarse-to-fine levels follow
    the resumed run's iters: a finished run extended by resuming is past its ramp and keeps every
    level on."""
    c = cfg.model_dump(mode="json")
    if cfg.lr_final is None:
        c.pop("iters")
    c.pop("checkpoint_every")
    c.pop("heap_cache")
    c.pop("device")
    # every field backend computes the same maths, so a checkpoint moves between machines and backends
    f = field.config.model_dump(mode="json", exclude={"backend"}) if isinstance(field, ScatteringField) else None
    return {"train": c, "field": f, "pings": data.pings.tolist(), "energy": data.energy}


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint written by :func:`fit` (a dict; see ``fit``)."""
    return torch.load(Path(path), map_location=map_location, weights_only=False)


def fit(field: torch.nn.Module, survey, signals: np.ndarray, config: TrainConfig | None = None,
        progress: ProgressFn | None = None, should_stop: StopFn | None = None,
        checkpoint_dir: str | Path | None = None, ping_indices: Sequence[int] | None = None,
        stage: str = "fit", psf: np.ndarray | None = None,
        occupancy: OccupancyGrid | None = None) -> FitResult:
    """Train ``field`` so that rendered pings match ``signals``.

    Args:
        field: an ``SHField`` (or any module with its ``forward``); trained in place, moved to
            the config's device.
        survey: geometry, time axis, scene box and beam metadata.
        signals: (N, T) complex pulse-deconvolved signals s_PD on the survey's time axis.
        config: :class:`TrainConfig`.
        progress: ``progress(fraction, stage, {"loss", "data_loss", "it/s"})`` once per iteration.
        should_stop: polled between iterations; when it returns True a checkpoint is written
            (if ``checkpoint_dir``) and :class:`~shsas_core.common.errors.Cancelled` is raised.
        checkpoint_dir: where ``checkpoint.pt`` is written every ``checkpoint_every`` iterations
            and at the end; if it already holds a compatible checkpoint, training resumes from it.
        ping_indices: training pings (default all); hold the rest out for novel views.
        stage: stage name reported to ``progress``.
        psf: (2h + 1,) complex point-spread kernel of the deconvolved data (``psf[h]`` at lag 0,
            :func:`~shsas_core.signal.deconv.point_spread`). When given, the rendered impulse response
            of contiguous bins is convolved with it before it is compared with the data, so a thin
            surface explains a PSF-wide echo (``cfg.psf_window`` target bins per ping).
        occupancy: where the field may be non-zero (:mod:`shsas_core.neural.fields.occupancy`); the
            field is rendered as ``within(field, occupancy)``, evaluated only there. Render
            and extract the trained field through the same mask.

    Returns:
        :class:`FitResult`.

    Raises:
        ShsasError: bad signals/config, or a checkpoint from a different configuration.
        Cancelled: ``should_stop()`` returned True.
    """
    cfg = config or TrainConfig()
    progress = progress or no_progress
    device = resolve_device(cfg.device)
    t_start = time.perf_counter()
    data = _prepare(survey, signals, ping_indices, cfg.uniform_fraction, cfg.target)
    field.to(device)
    dtype = device_dtype(field)[1]
    if cfg.progressive_sh_every is not None and not isinstance(field, ScatteringField):
        raise ShsasError("fit: progressive_sh_every needs a ScatteringField (set_active_degree), e.g. SHField")
    # a plain module (a test or benchmark stand-in) has no hash levels to bring in
    levels_ramp = cfg.coarse_to_fine if isinstance(field, ScatteringField) else None
    amp_mod = _Amplitude().to(device)
    params = list(field.parameters()) + ([amp_mod.log_amplitude] if cfg.learn_amplitude else [])
    opt = torch.optim.Adam(params, lr=cfg.lr)
    box = survey.meta.scene_box
    tv_delta = cfg.tv_delta if cfg.tv_delta is not None else float(np.linalg.norm(box.size)) / 128
    fp = _fingerprint(cfg, field, data)
    model = within(field, occupancy)
    if occupancy is not None:
        occupancy.to(device)
        fp["occupancy"] = occupancy.digest()
    psf_t = None
    if psf is not None:
        k = np.asarray(psf, dtype=np.complex128).ravel()
        if k.size % 2 != 1 or not np.all(np.isfinite(k)):
            raise ShsasError(f"fit: psf must be a finite kernel of odd length, got {k.size} taps")
        psf_t = torch.as_tensor(k.astype(np.complex64), device=device)
        fp["psf"] = [[float(v.real), float(v.imag)] for v in k]

    avg = _tail_average(field, cfg)
    avg_from = _average_start(cfg)
    ckpt_path = Path(checkpoint_dir) / CHECKPOINT_NAME if checkpoint_dir is not None else None
    loss_hist: list[float] = []
    data_hist: list[float] = []
    start = 0
    if ckpt_path is not None and ckpt_path.exists():
        ck = load_checkpoint(ckpt_path, device)
        if ck.get("fingerprint") != json.loads(json.dumps(fp)):
            raise ShsasError(f"fit: checkpoint {ckpt_path} was made with a different configuration, "
                             "survey or field (fix: use a new output directory or delete it)")
        field.load_state_dict(ck["field"])
        amp_mod.load_state_dict(ck["amplitude"])
        opt.load_state_dict(ck["optimizer"])
        if avg is not None:
            _resume_average(avg, ck, avg_from, cfg, ckpt_path)
        start = int(ck["iteration"])
        loss_hist, data_hist = list(ck["loss_history"]), list(ck["data_loss_history"])
        torch.set_rng_state(ck["rng"]["torch"])
        np.random.set_state(ck["rng"]["numpy"])
        random.setstate(ck["rng"]["python"])
        if torch.cuda.is_available() and ck["rng"].get("cuda") is not None:
            torch.cuda.set_rng_state_all(ck["rng"]["cuda"])
    elif ckpt_path is not None:
        ckpt_path.parent.mkdir(parents=True, exist_ok=True)

    def save() -> None:
        if ckpt_path is None:
            return
        rng = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
               "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None}
        _atomic_save({"iteration": it_done, "field": field.state_dict(), "amplitude": amp_mod.state_dict(),
                      "optimizer": opt.state_dict(), "loss_history": loss_hist,
                      "data_loss_history": data_hist, "rng": rng, "fingerprint": fp,
                      "config": cfg.model_dump(mode="json"), "signal_energy": data.energy,
                      "field_config": fp["field"],
                      "average": avg.state_dict() if avg is not None else None,
                      "average_from": avg_from if avg is not None else None}, ckpt_path)

    if start == 0:
        _init_amplitude(model, amp_mod, data, survey, cfg, device, dtype, psf_t)
    it_done = start
    t_loop = time.perf_counter()
    with heap_cache(cfg.heap_cache and device.type == "cpu"):
        try:
            for it in range(start, cfg.iters):
                check_stop(should_stop)
                if cfg.progressive_sh_every is not None:
                    field.set_active_degree(it // cfg.progressive_sh_every)
                if levels_ramp is not None:
                    field.set_active_levels(active_levels(field.config.encoding, levels_ramp, it, cfg.iters))
                if cfg.lr_final is not None:
                    for group in opt.param_groups:
                        group["lr"] = _scheduled_lr(cfg, it)
                loss, data_loss = _iteration_loss(model, amp_mod, data, survey, cfg, it, device, dtype, tv_delta,
                                                  psf_t)
                loss_value = float(loss.detach())
                if not math.isfinite(loss_value):
                    # nothing is stepped or saved: the last checkpoint stays the last good state
                    raise ShsasError(f"fit: the loss became {loss_value} at iteration {it} (training "
                                     f"diverged; fix: a lower learning rate, e.g. {cfg.lr / 3:.3g})")
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                if avg is not None and it >= avg_from:
                    avg.update_parameters(field)
                it_done = it + 1
                loss_hist.append(loss_value)
                data_hist.append(float(data_loss.detach()))
                rate = (it_done - start) / max(time.perf_counter() - t_loop, 1e-9)
                progress(it_done / cfg.iters, stage, {"loss": loss_hist[-1], "data_loss": data_hist[-1], "it/s": rate})
                if it_done % cfg.checkpoint_every == 0:
                    save()
        except Cancelled:
            save()
            raise
        finally:
            if cfg.progressive_sh_every is not None:
                field.set_active_degree(None)
            if levels_ramp is not None:
                field.set_active_levels(None)
    elapsed_loop = time.perf_counter() - t_loop
    save()
    if avg is not None and it_done > avg_from:  # after save(): a resumed run continues from the iterate
        with torch.no_grad():
            for p, q in zip(field.parameters(), avg.module.parameters(), strict=True):
                p.copy_(q)
    return FitResult(loss_history=loss_hist, data_loss_history=data_hist,
                     iters_per_s=(it_done - start) / elapsed_loop if it_done > start and elapsed_loop > 0 else 0.0,
                     iterations=it_done, start_iteration=start, amplitude=float(amp_mod().detach()),
                     signal_energy=data.energy, checkpoint_path=str(ckpt_path) if ckpt_path else None,
                     elapsed_s=time.perf_counter() - t_start)


def evaluate_data_loss(field: torch.nn.Module, survey, signals: np.ndarray, ping_indices: Sequence[int],
                       target: Target = TARGET, num_rays: int = NUM_RAYS,
                       amplitude: float | None = None, uniform_fraction: float = UNIFORM_FRACTION,
                       seed: int = SEED) -> float:
    """Relative data residual of whole pings, a low-noise version of the training data term.

    ``Σ p_nk |A ŝ_nk - s_nk|² / Σ p_nk |s_nk|²`` over every valid bin ``k`` of the given pings,
    with ``p`` the trainer's bin-sampling weights (``(1-u)|s|/Σ|s| + u/n_valid`` per ping), ``ŝ``
    rendered by :func:`~shsas_core.neural.render.render_transients` with ``num_rays`` rays, and ``s``
    the signals (``|s|`` for ``target="envelope"``). 0 is a perfect fit; predicting zeros scores 1.

    Args:
        field: trained (or freshly initialised) field. survey, signals: as for :func:`fit`.
        ping_indices: which pings. target: as ``TrainConfig.target``. num_rays: rays per ping.
        amplitude: the scale A (``FitResult.amplitude``); None: the least-squares best A >= 0 for
            these pings, which makes the value independent of the field's overall scale (use it
            to compare an untrained field with a trained one fairly).
        uniform_fraction: ``u`` of the weights. seed: ray jitter seed.
    """
    from shsas_core.neural.render.renderer import RenderConfig, render_transients

    pings = np.asarray(ping_indices, dtype=np.int64)
    s = np.asarray(signals)[pings]
    s = np.abs(s).astype(np.float64) if target == "envelope" else s.astype(np.complex128)
    p = _bin_weights(np.abs(s), _window_mask(survey, pings), uniform_fraction)
    den = float((p * np.abs(s) ** 2).sum())
    if not den > 0:
        raise ShsasError("evaluate_data_loss: the signals are all zero inside the scene's range window")
    pred = render_transients(field, survey, pings, RenderConfig(num_rays=num_rays), seed=seed).astype(np.complex128)
    if amplitude is None:
        e_pred = float((p * np.abs(pred) ** 2).sum())
        amplitude = max(float((p * (np.conj(pred) * s)).sum().real) / e_pred, 0.0) if e_pred > 0 else 0.0
    return float((p * np.abs(amplitude * pred - s) ** 2).sum()) / den


def _average_start(cfg: TrainConfig) -> int:
    """The steps after which the iterates are averaged (the last ``average_last`` of them, at
    least one; ``iters`` when nothing is averaged)."""
    if cfg.average_last is None:
        return cfg.iters
    return cfg.iters - max(1, round(cfg.average_last * cfg.iters))


def _tail_average(field: torch.nn.Module, cfg: TrainConfig) -> torch.nn.Module | None:
    """A running uniform mean of ``field``'s parameters (torch's ``AveragedModel``), or None."""
    if cfg.average_last is None:
        return None
    from torch.optim.swa_utils import AveragedModel

    return AveragedModel(field, use_buffers=False)  # its default: the running uniform mean


def _resume_average(avg: torch.nn.Module, ck: dict[str, Any], avg_from: int, cfg: TrainConfig,
                    path: Path) -> None:
    """Restore the weight average of checkpoint ``ck`` into ``avg``, or start it afresh when the
    resumed run (more iterations) averages a span that begins after the checkpoint."""
    start = int(ck["iteration"])
    if ck.get("average_from") == avg_from and ck.get("average") is not None:
        avg.load_state_dict(ck["average"])
    elif start > avg_from:
        frac = cfg.average_last
        assert frac is not None  # there is an average to resume
        fix = (f"{math.ceil(start / (1 - frac))} iterations or more" if frac < 1 else "a new output directory")
        raise ShsasError(f"fit: checkpoint {path} is at iteration {start}, past iteration {avg_from} "
                         f"where this run's weight average begins (average_last {frac:g} of "
                         f"{cfg.iters} iterations); fix: {fix}")


def _scheduled_lr(cfg: TrainConfig, it: int) -> float:
    """lr · (lr_final / lr)^(it / (iters - 1)): a pure function of the iteration, so resume is exact."""
    if cfg.lr_final is None or cfg.iters <= 1:
        return cfg.lr
    return cfg.lr * (cfg.lr_final / cfg.lr) ** (it / (cfg.iters - 1))


def _init_amplitude(field, amp_mod: _Amplitude, data: _Data, survey, cfg: TrainConfig, device, dtype,
                    psf: torch.Tensor | None = None, batches: int = 8) -> None:
    """Closed-form start for A: ‖s‖ / ‖ŝ‖ summed over ``batches`` seeded batches (streams
    1..batches of iteration 0), so one unusual view does not set the scale for all."""
    num = den = 0.0
    for j in range(batches):
        gen = _generator(cfg.seed, 0, stream=1 + j)
        with torch.enable_grad():
            _out, _geom, pred, target = _predict(field, amp_mod, data, survey, cfg, gen, device, dtype, psf,
                                          create_graph=False)
        num += float(target.abs().pow(2).sum())
        den += float((pred.detach() / amp_mod().detach().to(pred.real.dtype)).abs().pow(2).sum())
    num, den = math.sqrt(num), math.sqrt(den)
    if den > 0 and num > 0 and math.isfinite(num / den):
        with torch.no_grad():
            amp_mod.log_amplitude.fill_(math.log(num / den))
