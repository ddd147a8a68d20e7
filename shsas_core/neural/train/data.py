"""The training signals and the batch sampler: which pings, bins and targets each iteration sees.

Every draw of iteration ``i`` comes from :func:`iteration_generator` ``(seed, i)``, so the draws
do not depend on history (what makes resume exact).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from shsas_core.common.errors import ShsasError
from shsas_core.data.geometry import two_way_range_bounds
from shsas_core.neural.render.renderer import passband_factor, ping_geometry
from shsas_core.neural.render.sampling import bin_radii, sample_bins
from shsas_core.neural.train.config import TrainConfig


@dataclasses.dataclass
class TrainingData:
    """Training signals and per-ping range axes on the CPU (moved per batch)."""

    signals: torch.Tensor  # (N, T) complex64
    magnitude: torch.Tensor  # (N, T) float32 |s|
    t0: np.ndarray  # (N,) s, first-sample times (radii are c (t0 + k / fs), made per batch)
    valid: torch.Tensor  # (N, T) bool, inside the scene's range window (and beyond the baseline)
    pings: np.ndarray  # (n_train,) indices of the training pings
    energy: float  # expected |s|^2 of a drawn bin (see prepare_data)


def window_mask(survey, pings: np.ndarray) -> np.ndarray:
    """(len(pings), T) bool: samples whose two-way path lies in the scene's range window and
    beyond the TX-RX baseline (the bins training may draw)."""
    radii = bin_radii(survey.t0[pings], survey.meta.fs, survey.meta.sound_speed, survey.num_samples)
    r_lo, r_hi = two_way_range_bounds(survey.tx[pings], survey.rx[pings], survey.meta.scene_box)
    base = np.linalg.norm(survey.tx[pings] - survey.rx[pings], axis=1)
    return (radii >= r_lo[:, None]) & (radii <= r_hi[:, None]) & (radii > base[:, None])


def bin_weights(mag: np.ndarray, valid: np.ndarray, uniform_fraction: float) -> np.ndarray:
    """The bin sampler's pdf per ping, ``(1-u) |s| / Σ|s| + u / n_valid`` over the valid bins
    (uniform where a ping's valid bins are all zero): mag, valid (N, T) -> (N, T)."""
    n_valid = np.maximum(valid.sum(axis=1, keepdims=True), 1)
    w = np.where(valid, mag, 0.0)
    tot = w.sum(axis=1, keepdims=True)
    shape = np.where(tot > 0, w / np.where(tot > 0, tot, 1), valid / n_valid)
    return (1 - uniform_fraction) * shape + uniform_fraction * valid / n_valid


def prepare_data(survey, signals: np.ndarray, ping_indices: Sequence[int] | None,
                 uniform_fraction: float, target: str = "coherent") -> TrainingData:
    """Check ``signals`` (N, T) complex s_PD, keep the training pings that see the scene box and
    compute the data term's normaliser ``E`` (see :mod:`shsas_core.neural.train`)."""
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
    valid = window_mask(survey, np.arange(survey.num_pings))
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
    p = bin_weights(mag, valid[pings], uniform_fraction)
    energy = float(np.mean((p * mag**2).sum(axis=1)))
    if not energy > 0:
        raise ShsasError("fit: the signals are all zero inside the scene's range window")
    return TrainingData(torch.from_numpy(s.astype(np.complex64)), torch.from_numpy(np.abs(s).astype(np.float32)),
                        np.asarray(survey.t0, dtype=np.float64), torch.from_numpy(valid), pings, energy)


def iteration_generator(seed: int, iteration: int, stream: int = 0) -> torch.Generator:
    """The generator of every random draw of ``iteration`` (``stream`` > 0: side draws)."""
    # SeedSequence mixes (seed, iteration, stream) into well-separated 64-bit seeds
    s = np.random.SeedSequence([seed, iteration, stream]).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(s) & ((1 << 63) - 1))


def _pick_pings(data: TrainingData, cfg: TrainConfig, it_gen: torch.Generator) -> np.ndarray:
    """The iteration's training pings, sorted (the first draw from ``it_gen``)."""
    n_train = len(data.pings)
    pick = torch.randperm(n_train, generator=it_gen)[: min(cfg.pings_per_batch, n_train)].numpy()
    return np.sort(data.pings[pick])


def _bin_geometry(data: TrainingData, survey, pings: np.ndarray, bins: torch.Tensor, cfg: TrainConfig, device, dtype):
    """(ping geometry, two-way radii (B, K) of the sample indices ``bins``, m)."""
    meta = survey.meta
    r = meta.sound_speed * (data.t0[pings][:, None] + bins.numpy() / meta.fs)  # same formula as bin_radii
    radii = torch.as_tensor(r, dtype=dtype, device=device)
    return ping_geometry(survey, pings, device, dtype, cfg.render.beamwidth_deg), radii


def sample_batch(data: TrainingData, survey, it_gen: torch.Generator, cfg: TrainConfig, device, dtype):
    """Pings, bins and their targets of one iteration (all draws from ``it_gen``)."""
    pings = _pick_pings(data, cfg, it_gen)
    idx, _pdf = sample_bins(data.magnitude[pings], data.valid[pings], cfg.num_bins, cfg.uniform_fraction, it_gen)
    target = data.signals[torch.as_tensor(pings)[:, None], idx].to(device)
    geom, radii = _bin_geometry(data, survey, pings, idx, cfg, device, dtype)
    return pings, geom, radii, target


def sample_psf_batch(data: TrainingData, survey, it_gen: torch.Generator, cfg: TrainConfig, half: int, device, dtype):
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

