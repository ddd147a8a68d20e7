"""Where to look: importance-sampled range bins and stratified TX rays inside the beam cone.

Randomness comes only from an explicit ``torch.Generator`` on the CPU (draws are moved to the
compute device afterwards), so a seed fixes every sample on every device and a resumed training
run draws exactly what an uninterrupted one would.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import sample_times

#: Golden-ratio conjugate: consecutive multiples spread azimuths evenly (Fibonacci lattice).
_GOLDEN = 0.6180339887498949


def bin_radii(t0: np.ndarray, fs: float, c: float, num_samples: int) -> np.ndarray:
    """Two-way path length of every sample, ``r = c (t0 + k / fs)``: (N,) s -> (N, T) m."""
    return c * sample_times(t0, fs, num_samples)


def sample_bins(weights: Tensor, valid: Tensor, k: int, uniform_fraction: float,
                generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Draw ``k`` distinct range bins per ping, importance-sampled by signal magnitude.

    The sampling distribution over the valid bins of each ping is
    ``p = (1 - u) |s| / sum |s| + u / n_valid`` (``u = uniform_fraction``), so bins with echoes are
    visited often while empty bins still teach the field to stay empty. Draws are without
    replacement and returned sorted by index (= by radius), the order transmittance needs.

    Args:
        weights: (B, T) non-negative importance, e.g. ``|s_PD|`` (CPU tensor).
        valid: (B, T) bool, bins that may be drawn (inside the scene's range window).
        k: bins per ping; lowered to the smallest number of valid bins in the batch.
        uniform_fraction: share ``u`` in [0, 1] of the uniform component.
        generator: CPU generator.

    Returns:
        idx: (B, k') int64 sorted bin indices.
        pdf: (B, k') float64 probability of each drawn bin under ``p`` (per single draw).
    """
    if not 0.0 <= uniform_fraction <= 1.0:
        raise ShsasError(f"uniform_fraction: must be in [0, 1], got {uniform_fraction}")
    w = torch.where(valid, weights.to(torch.float64).clamp_min(0.0), torch.zeros((), dtype=torch.float64))
    n_valid = valid.sum(dim=1)
    if int(n_valid.min()) == 0:
        raise ShsasError("sample_bins: a ping has no range bin inside the scene window "
                         "(fix: check t0/scene box or drop that ping)")
    total = w.sum(dim=1, keepdim=True)
    shape = torch.where(total > 0, w / total.clamp_min(1e-300), valid.to(torch.float64) / n_valid[:, None])
    p = (1.0 - uniform_fraction) * shape + uniform_fraction * valid.to(torch.float64) / n_valid[:, None]
    nonzero = (p > 0).sum(dim=1)
    k_eff = int(min(k, int(nonzero.min())))
    idx = torch.multinomial(p, k_eff, replacement=False, generator=generator)
    idx, _ = torch.sort(idx, dim=1)
    return idx, torch.gather(p, 1, idx)


def beam_axes(tx: np.ndarray, tx_dir: np.ndarray | None, box_center: np.ndarray) -> np.ndarray:
    """Beam pointing per ping: the survey's ``tx_dir`` if given, else towards the scene-box centre.

    Returns (N, 3) unit vectors.
    """
    axis = (np.asarray(tx_dir, dtype=np.float64) if tx_dir is not None
            else np.asarray(box_center, dtype=np.float64)[None, :] - tx)
    n = np.linalg.norm(axis, axis=1, keepdims=True)
    if np.any(n < 1e-12):
        raise ShsasError("beam axis: a TX sits at the scene-box centre (fix: give tx_dir)")
    return axis / n


def cone_half_angles(tx: np.ndarray, axis: np.ndarray, box_min, box_max,
                     beamwidth_deg: float | None) -> np.ndarray:
    """Half-angle (rad) of the TX cone per ping.

    With a beam width (full cone angle, degrees) it is half of it. Otherwise the smallest cone
    about ``axis`` that contains the 8 scene-box corners, so every scene point can be hit.
    A TX inside the box gets the whole sphere (pi).
    """
    n = len(tx)
    if beamwidth_deg is not None:
        if not 0 < beamwidth_deg <= 360:
            raise ShsasError(f"beamwidth: must be in (0, 360] degrees, got {beamwidth_deg}")
        return np.full(n, min(math.radians(beamwidth_deg) / 2, math.pi))
    lo, hi = np.asarray(box_min, dtype=np.float64), np.asarray(box_max, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    vec = corners[None, :, :] - tx[:, None, :]
    vec /= np.linalg.norm(vec, axis=2, keepdims=True).clip(1e-12)
    ang = np.arccos(np.clip(np.einsum("nci,ni->nc", vec, axis), -1.0, 1.0)).max(axis=1)
    inside = np.all((tx >= lo) & (tx <= hi), axis=1)
    return np.where(inside, math.pi, np.minimum(ang * 1.0001, math.pi))


def _orthonormal_basis(axis: Tensor) -> tuple[Tensor, Tensor]:
    helper = torch.zeros_like(axis)
    use_x = axis[..., 2].abs() > 0.9
    helper[..., 0] = torch.where(use_x, 1.0, 0.0).to(axis.dtype)
    helper[..., 2] = torch.where(use_x, 0.0, 1.0).to(axis.dtype)
    e1 = torch.linalg.cross(helper, axis)
    e1 = e1 / e1.norm(dim=-1, keepdim=True)
    return e1, torch.linalg.cross(axis, e1)


def cone_directions(axis: Tensor, half_angle: Tensor, m: int, generator: torch.Generator | None,
                    jitter: bool = True) -> tuple[Tensor, Tensor]:
    """``m`` stratified ray directions per ping, uniform in solid angle inside the cone.

    Ray ``i`` takes the ``i``-th of ``m`` equal-solid-angle strata in ``cos theta`` (jittered
    inside its stratum) and an azimuth from a Fibonacci lattice rotated by a random offset, so
    the rays cover the cone evenly and each stands for ``Omega / m`` steradians.

    Args:
        axis: (B, 3) unit beam axes; half_angle: (B,) rad.
        m: rays per ping. generator: CPU generator (None or ``jitter=False``: stratum centres).

    Returns:
        dirs: (B, m, 3) unit vectors (axis dtype/device). solid_angle: (B,) cone solid angle, sr.
    """
    b = axis.shape[0]
    dtype, dev = axis.dtype, axis.device
    if jitter and generator is not None:
        xi = torch.rand((b, m), generator=generator, dtype=torch.float64)
        rot = torch.rand((b, 1), generator=generator, dtype=torch.float64)
    else:
        xi = torch.full((b, m), 0.5, dtype=torch.float64)
        rot = torch.zeros((b, 1), dtype=torch.float64)
    i = torch.arange(m, dtype=torch.float64)[None, :]
    cos_a = torch.cos(half_angle.detach().to("cpu", torch.float64))[:, None]
    cos_t = 1.0 - (i + xi) / m * (1.0 - cos_a)
    sin_t = (1.0 - cos_t * cos_t).clamp_min(0.0).sqrt()
    phi = 2.0 * math.pi * torch.remainder(i * _GOLDEN + rot, 1.0)
    local = torch.stack([sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t], dim=-1).to(dev, dtype)
    e1, e2 = _orthonormal_basis(axis)
    dirs = local[..., 0:1] * e1[:, None] + local[..., 1:2] * e2[:, None] + local[..., 2:3] * axis[:, None]
    solid = (2.0 * math.pi * (1.0 - cos_a[:, 0])).to(dev, dtype)
    return dirs, solid
