"""A neural field sampled on a voxel grid: the volume extraction and the metrics read."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from shsas_core.common.errors import ShsasError
from shsas_core.data.volume import Grid, Volume
from shsas_core.neural.fields.base import device_dtype


def field_volume(field: Any, grid: Grid, chunk: int = 65536, name: str = "") -> Volume:
    """Sample ``|σ_DC|`` of a neural field on ``grid`` (no gradients, in chunks).

    σ_DC is the degree-0 term ``c_00 · Y_00`` of the SH expansion (Y_00 = 1/√(4π)), the isotropic
    scattering that also defines the density.

    Args:
        field: a module with ``coefficients(x: (P,3) m) -> (P,(L+1)²) complex`` (``SHField``).
        grid: where to sample.
        chunk: points per forward pass; bounds peak memory.
    Returns:
        Volume of float32 magnitudes, shape ``grid.shape``.
    """
    import torch

    if chunk < 1:
        raise ShsasError(f"field_volume chunk: must be >= 1, got {chunk}")
    device, dtype = device_dtype(field)
    pts = grid.points()
    out = np.empty(len(pts), dtype=np.float32)
    y00 = 1.0 / math.sqrt(4.0 * math.pi)
    with torch.no_grad():
        for s in range(0, len(pts), chunk):
            x = torch.as_tensor(pts[s:s + chunk], dtype=dtype, device=device)
            c00 = field.coefficients(x)[:, 0]
            out[s:s + chunk] = (c00.abs() * y00).float().cpu().numpy()
    return Volume(grid, out.reshape(grid.shape), name=name or "|sigma_DC|")
