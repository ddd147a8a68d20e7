"""Start a neural field from an image: distil a complex backprojection volume into the field.

A hash-grid field trained from scratch on time-of-flight data needs thousands of GPU iterations
before a surface forms; at CPU budgets it stays a fog (docs/neural.md). The backprojection image
already holds the geometry (and, for a coherent image, the phase each scatterer echoes with), so
the neural methods first regress the field's isotropic term onto it and only then refine it
through the forward model:

    min_θ  E_u [ |σ_DC(x(u); θ) - p · I(x(u)) / max|I||² ]      u ~ U([0, 1]^3), x = box.min + u·box.size

``σ_DC = c_00 / √(4π)`` is the field's degree-0 scattering, ``I`` the image read by trilinear
interpolation between voxel centres, and ``p`` (``WarmStartConfig.peak``) the σ_DC given to the
brightest voxel. A complex image sets ``Re`` and ``Im`` of ``c_00``; a real one (a magnitude
image) sets ``|c_00|``. The directional coefficients (degree ≥ 1) are left near zero, so the
started field scatters isotropically, as backprojection assumes.

Why this is consistent with the renderer: a point scatterer at ``x0`` with coefficient ``σ0``
backprojects to ``I(x0) ∝ σ0`` with its phase (backprojection restores the carrier phase per
voxel), and the renderer adds ``σ(x)`` to a bin with that same phase (:mod:`shsas_core.neural.render`).
So the rendered pings of a distilled field already resemble the data up to the imaging operator's
blur, and the refinement starts close.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import ShsasError
from shsas_core.common.optim import adam
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, no_progress
from shsas_core.data.volume import Volume
from shsas_core.neural.fields.base import device_dtype
from shsas_core.neural.fields.field import INV_SQRT_4PI
from shsas_core.neural.fields.occupancy import OccupancyGrid


class WarmStartConfig(BaseModel):
    """How an image is distilled into a field (module doc)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(300, ge=1, le=100_000, description="Adam steps of the regression")
    batch: int = Field(32768, ge=1, le=1 << 22, description="random points per step")
    lr: float = Field(1e-2, gt=0, le=1.0, description="Adam learning rate of the regression")
    peak: float = Field(1.0, gt=0, description="σ_DC (1/m as density) given to the brightest voxel")
    seed: int = Field(0, ge=0, le=2**31 - 1)


@dataclasses.dataclass
class WarmStartResult:
    """What :func:`distill` returns: the regression loss per step (mean squared error of σ_DC,
    in (1/m)²) and the loss of the last step relative to the target's mean square."""

    loss_history: list[float]
    relative_error: float


def image_target(volume: Volume, peak: float) -> torch.Tensor:
    """The regression target on the image grid: (1, C, nx, ny, nz) float32, C = 2 (Re, Im) for a
    complex volume, 1 (magnitude) for a real one, scaled so the brightest voxel has ``peak``."""
    v = np.asarray(volume.values)
    top = float(np.abs(v).max()) if v.size else 0.0
    if not (top > 0 and math.isfinite(top)):
        raise ShsasError("warm start: the image is all zero or not finite (fix: check the survey's "
                         "signals, or start from scratch with init='none')")
    parts = [v.real, v.imag] if np.iscomplexobj(v) else [np.abs(v)]
    return torch.from_numpy(np.stack(parts).astype(np.float32) * np.float32(peak / top))[None]


def sample_image(target: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Trilinear read of ``target`` (1, C, nx, ny, nz) at unit-box points ``u`` (P, 3) in [0, 1]^3
    (voxel centres at (i + 0.5) / n, clamped at the borders): returns (C, P)."""
    p = u.shape[0]
    # grid_sample wants (x, y, z) -> (W, H, D) = (nz, ny, nx) order, coordinates in [-1, 1] with
    # align_corners=False mapping -1 to the outer face of the first voxel, as Grid does
    g = (u * 2 - 1)[:, [2, 1, 0]].reshape(1, p, 1, 1, 3).to(target.dtype)
    out = F.grid_sample(target, g, mode="bilinear", padding_mode="border", align_corners=False)
    return out.reshape(target.shape[1], p)


def distill(field: torch.nn.Module, volume: Volume, config: WarmStartConfig | None = None,
            progress: ProgressFn = no_progress, should_stop: StopFn | None = None,
            stage: str = "warm start", occupancy: OccupancyGrid | None = None) -> WarmStartResult:
    """Regress the field's σ_DC onto ``volume`` (module doc); trains ``field`` in place.

    Args:
        field: a :class:`~shsas_core.neural.fields.ScatteringField`-like module with
            ``coefficients(x (P,3) m) -> (P, K) complex``; its parameters' device and dtype are used.
        volume: the image on a grid covering (at least) the field's scene box: complex (a
            backprojection) or real (a magnitude).
        config: :class:`WarmStartConfig`.
        progress: ``progress(fraction, stage, {"loss"})`` per step. should_stop: polled per step.
        occupancy: the mask the field will be trained and read through (``within(field,
            occupancy)``), or None. Each step's random points outside it are dropped: the masked
            model never reads the field there, so regressing it there only costs time (on a real
            survey whose mask is a third of the box, two thirds of the work). A step with no
            point inside is skipped; a mask over the whole box changes nothing.
    Returns:
        :class:`WarmStartResult`.
    """
    cfg = config or WarmStartConfig()
    device, dtype = device_dtype(field)
    target = image_target(volume, cfg.peak).to(device)
    lo = torch.as_tensor(volume.grid.box_min, dtype=torch.float64)
    size = torch.as_tensor(np.asarray(volume.grid.box_max) - np.asarray(volume.grid.box_min), dtype=torch.float64)
    gen = torch.Generator().manual_seed(cfg.seed)
    opt = adam(field.parameters(), lr=cfg.lr)
    complex_target = target.shape[1] == 2
    mean_sq = float(target.pow(2).sum(1).mean())
    history: list[float] = []
    for step in range(cfg.steps):
        check_stop(should_stop)
        u = torch.rand(cfg.batch, 3, generator=gen, dtype=torch.float64)
        if occupancy is not None:
            keep = occupancy.lookup((lo + u * size).to(occupancy.box_min.device))
            if not bool(keep.all()):  # indexing only when needed: a full mask stays bit-identical
                u = u[keep.cpu()]
            if u.shape[0] == 0:
                continue
        x = (lo + u * size).to(device, dtype)
        want = sample_image(target, u.to(device, torch.float32)).to(dtype)
        c00 = field.coefficients(x)[:, 0] * INV_SQRT_4PI
        if complex_target:
            loss = (c00.real - want[0]).pow(2).mean() + (c00.imag - want[1]).pow(2).mean()
        else:
            loss = (c00.abs() - want[0]).pow(2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        history.append(float(loss.detach()))
        progress((step + 1) / cfg.steps, stage, {"loss": history[-1]})
    last = history[-1] if history else math.nan
    return WarmStartResult(history, last / mean_sq if mean_sq > 0 else math.nan)
