"""Voxel grids over the scene box, shared by backprojection, field sampling and extraction."""

from __future__ import annotations

import dataclasses

import numpy as np

from shsas_core.data.survey import SceneBox

#: Default extraction voxel, m: half the metrics' 5 mm occupancy voxel, so that a surface one voxel
#: thick still marks every metric voxel it crosses (at 5 mm, a reconstruction's voxel lattice
#: aliases against the metric's and caps its F1).
DEFAULT_VOXEL_M = 0.0025
#: Upper bound of the automatic count: 256^3 voxels are ~17 M points, the most a CPU job samples.
MAX_AUTO_GRID = 256


def auto_grid_count(box: SceneBox, voxel: float = DEFAULT_VOXEL_M) -> int:
    """Voxels along the longest axis of ``box`` so that voxels are at most ``voxel`` m (8..256)."""
    return int(min(MAX_AUTO_GRID, max(8, np.ceil(float(np.max(box.size)) / voxel - 1e-9))))


@dataclasses.dataclass(frozen=True)
class Grid:
    """A regular grid of voxel centres over an axis-aligned box.

    Attributes:
        box_min, box_max: (3,) box corners, m.
        shape: (nx, ny, nz) voxel counts.
    Voxel (i, j, k) has centre ``box_min + (idx + 0.5) * spacing``.
    """

    box_min: tuple[float, float, float]
    box_max: tuple[float, float, float]
    shape: tuple[int, int, int]

    @classmethod
    def over(cls, box: SceneBox, longest: int) -> Grid:
        """Grid with ``longest`` voxels on the longest axis and cubic voxels (rounded counts)."""
        size = box.size
        step = float(size.max()) / longest
        shape = tuple(max(1, round(float(s) / step)) for s in size)
        return cls(tuple(box.min), tuple(box.max), shape)  # type: ignore[arg-type]

    @property
    def spacing(self) -> np.ndarray:
        """(3,) voxel size per axis, m."""
        return (np.asarray(self.box_max) - np.asarray(self.box_min)) / np.asarray(self.shape)

    @property
    def num_voxels(self) -> int:
        return int(np.prod(self.shape))

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel-centre coordinates along x, y, z, m."""
        lo, d = np.asarray(self.box_min), self.spacing
        return tuple(lo[a] + (np.arange(self.shape[a]) + 0.5) * d[a] for a in range(3))  # type: ignore[return-value]

    def points(self) -> np.ndarray:
        """(nx*ny*nz, 3) float64 voxel centres in C order (x slowest, z fastest)."""
        x, y, z = self.axes()
        return np.stack(np.meshgrid(x, y, z, indexing="ij"), -1).reshape(-1, 3)


@dataclasses.dataclass
class Volume:
    """Values on a :class:`Grid`: complex backprojection images or real field magnitudes.

    Attributes:
        grid: the grid.
        values: array of ``grid.shape``, complex64 or float32.
        name: what the values are, e.g. ``"backprojection"`` or ``"shsas |sigma_DC|"``.
    """

    grid: Grid
    values: np.ndarray
    name: str = ""

    def __post_init__(self) -> None:
        if tuple(self.values.shape) != tuple(self.grid.shape):
            raise ValueError(f"values shape {self.values.shape} != grid shape {self.grid.shape}")

    def magnitude(self) -> np.ndarray:
        return np.abs(self.values).astype(np.float32)

    def normalized(self) -> np.ndarray:
        """|values| scaled to [0, 1] by the maximum (all zeros stay zeros)."""
        m = self.magnitude()
        peak = float(m.max()) if m.size else 0.0
        return m / peak if peak > 0 else m
