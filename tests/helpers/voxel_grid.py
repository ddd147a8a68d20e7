"""The voxel centres of a cubic test grid."""

from __future__ import annotations

import numpy as np


def voxel_centres(lo: np.ndarray, n: int, h: float) -> np.ndarray:
    """(n, n, n, 3) centres, m, of the n³ voxels of edge ``h`` m whose corner is ``lo`` (3,) m."""
    ax = lo[0] + (np.arange(n) + 0.5) * h
    return np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)
