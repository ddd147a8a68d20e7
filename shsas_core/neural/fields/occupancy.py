"""Occupancy grid: where a neural field may be non-zero, from the job's backprojection image.

instant-ngp's occupancy grid, in its simplest form: a boolean voxel mask over the scene box. The
renderer evaluates the field only where the mask is set and treats every other point as empty
(density 0, scattering 0, normal 0), so the field's cost follows the scene's occupied volume
instead of the scene box (on the dense bunny, 19 % of the points a training batch places are
occupied at the default level; 48 % are inside the box at all).

The mask is the backprojection image's normalised magnitude above ``level`` and above
``floor_factor`` times the image's median magnitude (its blur and clutter floor), dilated by
``dilate_voxels`` voxels: backprojection puts energy wherever a surface can be, so a low level
keeps every surface the data can show, and the dilation keeps room for the fit to move the
surface by a few voxels. :class:`MaskedField` wraps a field with the mask; the masked field is
the model, so training, rendering and extraction all see the same scene.
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from shsas_core.common.errors import ShsasError
from shsas_core.data.volume import Grid, Volume
from shsas_core.neural.fields.base import device_dtype


class OccupancyConfig(BaseModel):
    """How the mask is made from an image."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    level: float = Field(0.05, ge=0, lt=1, description="normalised |image| above which a voxel is occupied")
    dilate_voxels: int = Field(2, ge=0, le=64, description="voxels added around the occupied set")
    floor_factor: float = Field(2.0, ge=0, le=100, description="an occupied voxel must also exceed this "
                                "multiple of the image's median magnitude (its floor); 0: no floor test")


class OccupancyGrid(torch.nn.Module):
    """A boolean mask on a :class:`~shsas_core.data.volume.Grid` (a module, so it moves with ``.to``).

    Args:
        grid: where the mask's voxels are. mask: ``grid.shape`` bool.
    """

    def __init__(self, grid: Grid, mask: np.ndarray):
        super().__init__()
        m = np.asarray(mask, dtype=bool)
        if m.shape != tuple(grid.shape):
            raise ShsasError(f"occupancy: mask shape {m.shape} does not match the grid {tuple(grid.shape)}")
        self.grid = grid
        self.register_buffer("mask", torch.from_numpy(m.copy()), persistent=False)
        self.register_buffer("box_min", torch.tensor(grid.box_min, dtype=torch.float64), persistent=False)
        self.register_buffer("spacing", torch.tensor(grid.spacing, dtype=torch.float64), persistent=False)
        self.register_buffer("dims", torch.tensor(grid.shape, dtype=torch.int64), persistent=False)

    @classmethod
    def from_volume(cls, volume: Volume, cfg: OccupancyConfig | None = None) -> OccupancyGrid:
        """The mask of an image: normalised magnitude > ``cfg.level`` and magnitude >
        ``cfg.floor_factor`` x its median, dilated ``cfg.dilate_voxels``."""
        cfg = cfg or OccupancyConfig()
        mag = volume.magnitude().astype(np.float64)
        peak = float(mag.max()) if mag.size else 0.0
        if not np.isfinite(peak) or peak <= 0:
            raise ShsasError("occupancy: the image is empty (all zero or not finite)")
        mask = mag > cfg.level * peak
        if cfg.floor_factor > 0:
            # a real image carries a blur and clutter floor that can lie above ``level`` (on the
            # real AirSAS bunny the median voxel is at 0.085 of the peak): the level alone then
            # marks the whole box and the mask neither saves work nor bounds the field. The
            # floor is the median, which stays in the background while the scene fills less
            # than half the box; on a clean image ``floor_factor`` times it is below the level
            # and the mask is the level's alone
            mask &= mag > cfg.floor_factor * float(np.median(mag))
        if cfg.dilate_voxels:
            mask = ndimage.binary_dilation(mask, structure=ndimage.generate_binary_structure(3, 3),
                                           iterations=cfg.dilate_voxels)
        return cls(volume.grid, mask)

    @classmethod
    def full(cls, grid: Grid) -> OccupancyGrid:
        """Every voxel occupied: the field is evaluated everywhere inside the grid's box."""
        return cls(grid, np.ones(grid.shape, dtype=bool))

    @property
    def fraction(self) -> float:
        """Share of the voxels that are occupied."""
        return float(self.mask.float().mean())

    def digest(self) -> str:
        """A short hash of the grid and the mask (a checkpoint is resumed only with the same mask)."""
        h = hashlib.sha1(repr((self.grid.box_min, self.grid.box_max, self.grid.shape)).encode())
        h.update(np.packbits(self.mask.cpu().numpy()).tobytes())
        return h.hexdigest()[:16]

    def lookup(self, x: torch.Tensor) -> torch.Tensor:
        """Whether each point lies in an occupied voxel: x (P, 3) m -> (P,) bool (False outside
        the grid and for non-finite points)."""
        idx = torch.floor((x.detach().to(torch.float64) - self.box_min) / self.spacing)
        ok = torch.isfinite(idx).all(dim=1) & (idx >= 0).all(dim=1) & (idx < self.dims).all(dim=1)
        ijk = torch.where(ok[:, None], idx, torch.zeros_like(idx)).to(torch.int64)
        return ok & self.mask[ijk[:, 0], ijk[:, 1], ijk[:, 2]]


def _scatter(values: torch.Tensor, keep: torch.Tensor, n: int) -> torch.Tensor:
    """(n, ...) zeros with ``values`` at the rows ``keep`` (differentiable in ``values``)."""
    full = values.new_zeros((n, *values.shape[1:]))
    return full.index_put((keep,), values)


class MaskedField(torch.nn.Module):
    """``field`` inside the occupancy mask, empty outside it; evaluates ``field`` only where occupied.

    Same interface as :class:`~shsas_core.neural.fields.SHField` for the renderer and the extraction
    (``forward``, ``coefficients``); the parameters are the wrapped field's.
    """

    def __init__(self, field: torch.nn.Module, occupancy: OccupancyGrid):
        super().__init__()
        self.field = field
        self.occupancy = occupancy

    def forward(self, x: torch.Tensor, dirs: torch.Tensor, with_normals: bool = True,
                create_graph: bool | None = None) -> dict[str, torch.Tensor]:
        """As :meth:`SHField.forward`; unoccupied points get density 0, scattering 0, normal 0."""
        keep = torch.nonzero(self.occupancy.lookup(x), as_tuple=False)[:, 0]
        inner = self.field(x[keep], dirs[keep], with_normals=with_normals, create_graph=create_graph)
        return {k: _scatter(v, keep, x.shape[0]) for k, v in inner.items()}

    # the ScatteringField interface: the wrapped field's
    @property
    def config(self) -> Any:
        return self.field.config

    @property
    def device(self) -> torch.device:
        return device_dtype(self.field)[0]

    @property
    def dtype(self) -> torch.dtype:
        return device_dtype(self.field)[1]

    def set_active_degree(self, degree: int | None) -> None:
        self.field.set_active_degree(degree)

    def set_active_levels(self, levels: float | None) -> None:
        self.field.set_active_levels(levels)

    def coefficients(self, x: torch.Tensor) -> torch.Tensor:
        """Complex SH coefficients (P, (L+1)^2), zero outside the mask."""
        keep = torch.nonzero(self.occupancy.lookup(x), as_tuple=False)[:, 0]
        return _scatter(self.field.coefficients(x[keep]), keep, x.shape[0])


def within(field: torch.nn.Module, occupancy: OccupancyGrid | None) -> torch.nn.Module:
    """The model that is trained, rendered and extracted: ``field`` inside ``occupancy``'s mask
    (:class:`MaskedField`), or ``field`` itself when there is no mask. The one place the mask is
    put on a field."""
    return field if occupancy is None else MaskedField(field, occupancy)
