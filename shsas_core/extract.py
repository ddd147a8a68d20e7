"""Turn a reconstructed volume into geometry: a thresholded point cloud and a marching-cubes mesh.

Both backprojection images (complex ``|I|``) and neural fields (``|σ_DC|`` sampled on a grid by
:func:`field_volume`) arrive here as a :class:`~shsas_core.volume.Volume`. The magnitude is
normalised to [0, 1] by its range (``(m - min) / (max - min)``, :func:`normalize`), so the iso
level τ means the same for every method: a neural field's non-zero floor (fog) maps to 0 just
like a backprojection image's near-zero background.

Default τ (``ExtractConfig.rule = "otsu"``): Otsu's threshold of the normalised magnitude over the
whole grid, clipped to ``[tau_min, tau_max]``. Otsu picks the level that best splits the histogram
into two classes (empty space vs. scatterers) without assuming how much of the box the object
fills, which is what differs most between methods: a neural |σ_DC| is near zero almost
everywhere, a backprojection image carries a broad floor of sidelobes. The clip keeps the level
away from the floor of a nearly empty volume (Otsu would split noise from noise) and from the
single brightest voxel. ``rule = "percentile"`` keeps the voxels above a fixed percentile
instead, and an explicit ``threshold`` overrides both.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .errors import ShsasError
from .volume import Grid, Volume

#: The paper's fixed iso level on the normalised magnitude (reported beside the rule's τ).
PAPER_TAU = 0.2


class ExtractConfig(BaseModel):
    """How to turn a volume into a point cloud and a mesh."""

    model_config = ConfigDict(extra="forbid")

    threshold: float | None = Field(None, gt=0, lt=1, description="normalised iso level τ; None = rule")
    rule: Literal["otsu", "percentile"] = Field("otsu", description="rule for τ when threshold is None")
    percentile: float = Field(99.0, gt=0, lt=100, description="for rule='percentile': keep voxels above it")
    tau_min: float = Field(0.05, gt=0, lt=1, description="lower clip of the rule's τ")
    tau_max: float = Field(0.9, gt=0, lt=1, description="upper clip of the rule's τ")
    close_boundary: bool = Field(True, description="pad with empty voxels so meshes close at the box faces")
    chunk: int = Field(65536, ge=1, description="grid points per field evaluation (memory bound)")


@dataclasses.dataclass
class PointCloud:
    """Points with one scalar each.

    Attributes:
        points: (P, 3) float64 voxel centres, m, survey frame.
        scalars: (P,) float32 normalised magnitude in [τ, 1].
    """

    points: np.ndarray
    scalars: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


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
        raise ShsasError(f"extract.chunk: must be >= 1, got {chunk}")
    from .fields.base import device_dtype

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


def normalize(volume: Volume) -> np.ndarray:
    """``grid.shape`` float32 magnitude scaled to [0, 1] by its range (a constant volume gives 0)."""
    m = volume.magnitude()
    if m.size == 0:
        return m
    lo, hi = float(m.min()), float(m.max())
    if not hi > lo:
        return np.zeros_like(m)
    return ((m - lo) / (hi - lo)).astype(np.float32)


def otsu_threshold(values: np.ndarray, bins: int = 256) -> float:
    """Otsu's threshold of ``values`` (any shape): the level maximising between-class variance."""
    from skimage.filters import threshold_otsu

    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 0 or float(v.max()) == float(v.min()):
        return float(v.max()) if v.size else 0.0
    return float(threshold_otsu(v, nbins=bins))


def choose_threshold(volume: Volume, config: ExtractConfig | None = None) -> float:
    """τ for ``volume``: ``config.threshold`` if given, else the documented rule (module doc)."""
    cfg = config or ExtractConfig()
    if cfg.threshold is not None:
        return float(cfg.threshold)
    norm = normalize(volume)
    if cfg.rule == "otsu":
        tau = otsu_threshold(norm)
    else:
        tau = float(np.percentile(norm, cfg.percentile))
    return float(np.clip(tau, cfg.tau_min, cfg.tau_max))


def point_cloud(volume: Volume, tau: float) -> PointCloud:
    """Voxel centres whose normalised magnitude is >= ``tau``.

    Returns:
        PointCloud with (P, 3) survey-frame centres, m, and their normalised magnitudes.
    """
    _check_tau(tau)
    norm = normalize(volume)
    idx = np.argwhere(norm >= tau)
    lo, d = np.asarray(volume.grid.box_min), volume.grid.spacing
    pts = lo + (idx + 0.5) * d
    return PointCloud(pts.astype(np.float64), norm[tuple(idx.T)].astype(np.float32))


def mesh(volume: Volume, tau: float, close_boundary: bool = True):
    """Marching-cubes iso-surface of the normalised magnitude at ``tau``.

    Vertices are in survey-frame metres: skimage returns positions in units of ``spacing``
    measured from the centre of voxel (0, 0, 0), which sits at ``box_min + spacing/2`` (one voxel
    further out when the volume is padded to close the surface at the box faces).

    Returns:
        ``trimesh.Trimesh`` (empty when no voxel reaches ``tau``).
    """
    import trimesh
    from skimage.measure import marching_cubes

    _check_tau(tau)
    norm = normalize(volume)
    if norm.size == 0 or float(norm.max()) < tau or (min(norm.shape) < 2 and not close_boundary):
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    pad = 1 if close_boundary else 0
    if pad:
        norm = np.pad(norm, 1, mode="constant", constant_values=0.0)
    if float(norm.min()) > tau:  # whole box above τ and no padding: no crossing
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    d = volume.grid.spacing
    verts, faces, _normals, _ = marching_cubes(norm, level=tau, spacing=tuple(float(s) for s in d),
                                              allow_degenerate=False)
    origin = np.asarray(volume.grid.box_min) + (0.5 - pad) * d
    verts = verts.astype(np.float64) + origin
    # skimage's gradient direction makes faces wind inward for "bright inside" volumes; flip so
    # normals point out of the object (away from high magnitude), as viewers expect.
    faces = faces[:, ::-1].astype(np.int64)
    return trimesh.Trimesh(verts, faces, process=False)


def extract(volume: Volume, config: ExtractConfig | None = None) -> tuple[float, PointCloud, Any]:
    """τ by the config, then the point cloud and the mesh: ``(tau, PointCloud, Trimesh)``."""
    cfg = config or ExtractConfig()
    tau = choose_threshold(volume, cfg)
    return tau, point_cloud(volume, tau), mesh(volume, tau, cfg.close_boundary)


def threshold_sweep(volume: Volume, taus: Sequence[float],
                    score: Callable[[PointCloud, Any], dict[str, float]] | None = None,
                    close_boundary: bool = True) -> list[dict[str, float]]:
    """Extract at each τ and report sizes (and ``score(point_cloud, mesh)`` when given).

    Returns:
        One dict per τ: ``tau``, ``points``, ``faces`` plus the score's keys.
    """
    rows = []
    for tau in taus:
        pc = point_cloud(volume, float(tau))
        m = mesh(volume, float(tau), close_boundary)
        row = {"tau": float(tau), "points": float(len(pc)), "faces": float(len(m.faces))}
        if score is not None:
            row.update(score(pc, m))
        rows.append(row)
    return rows


def _check_tau(tau: float) -> None:
    if not (0.0 < float(tau) < 1.0) or not math.isfinite(float(tau)):
        raise ShsasError(f"threshold: τ must lie in (0, 1) on the normalised magnitude, got {tau}")
