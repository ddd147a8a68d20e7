"""Point scatterers for simulation, and occlusion tests against a mesh.

A surface is simulated as many point scatterers sampled uniformly by area, each carrying the
normal of its triangle and the area it stands for. The sampling rule: the mean spacing
``sqrt(area / M)`` of M points is at most ``spacing_fraction`` (default 1/4) of the shortest
wavelength ``c / f_max``, so the surface integral is resolved well below a wavelength.

Occlusion uses shadow rays: a point scatters toward a sensor only when the segment from the
point (lifted a little off the surface along its normal) to the sensor hits no triangle. With
``embreex`` installed, trimesh's Embree scene answers these as occlusion queries limited to the
segment length; otherwise trimesh's pure-numpy ray-triangle code does (slow, same answer).
"""

from __future__ import annotations

import dataclasses
import itertools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import trimesh

from shsas_core.common.errors import ShsasError
from shsas_core.common.threads import owned_cpus


@dataclasses.dataclass
class Scatterers:
    """M point scatterers.

    Attributes:
        points: (M, 3) float64 positions, m.
        normals: (M, 3) float64 unit surface normals, or None for isotropic points (no
            Lambertian or directional term, no back-face test).
        amplitude: (M,) float64 reflectivity weights (for a sampled surface: the area each
            point stands for, m²), or None for all ones.
        phase: (M,) float64 scattering phase, radians, or None for zero.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    amplitude: np.ndarray | None = None
    phase: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        m = len(self.points)
        if m == 0:
            raise ShsasError("no scatterers given")
        if not np.all(np.isfinite(self.points)):
            raise ShsasError("scatterer positions contain NaN or inf")
        if self.normals is not None:
            n = np.asarray(self.normals, dtype=np.float64).reshape(-1, 3)
            if n.shape != (m, 3):
                raise ShsasError(f"scatterer normals have shape {n.shape}, expected ({m}, 3)")
            norm = np.linalg.norm(n, axis=1, keepdims=True)
            if not np.all(np.isfinite(norm)) or np.any(norm < 1e-12):
                raise ShsasError("scatterer normals must be finite and non-zero")
            self.normals = n / norm
        for name in ("amplitude", "phase"):
            v = getattr(self, name)
            if v is not None:
                v = np.broadcast_to(np.asarray(v, dtype=np.float64), (m,)).copy()
                if not np.all(np.isfinite(v)):
                    raise ShsasError(f"scatterer {name} contains NaN or inf")
                setattr(self, name, v)

    def __len__(self) -> int:
        return len(self.points)


def points_for_spacing(area: float, spacing: float) -> int:
    """Number of points M whose mean spacing ``sqrt(area / M)`` is at most ``spacing``."""
    return max(1, int(np.ceil(area / spacing**2)))


def sample_surface(mesh: trimesh.Trimesh, count: int, seed: int = 0) -> Scatterers:
    """Sample ``count`` points uniformly by area on ``mesh``.

    Faces are drawn with probability proportional to their area and points uniformly inside
    each face (square-root barycentric trick), all from ``numpy.random.default_rng(seed)`` so
    the result does not depend on the trimesh version.

    Returns:
        Scatterers with face normals and ``amplitude`` = area per point (total area / count).
    """
    if count < 1:
        raise ShsasError(f"need at least one surface point, got {count}")
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    total = float(areas.sum())
    if not total > 0:
        raise ShsasError("mesh has zero surface area")
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(areas)
    face = np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right")
    face = np.minimum(face, len(areas) - 1)
    r1 = np.sqrt(rng.random(count))
    r2 = rng.random(count)
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)[face]]  # (M, 3, 3)
    pts = ((1 - r1)[:, None] * tri[:, 0] + (r1 * (1 - r2))[:, None] * tri[:, 1]
           + (r1 * r2)[:, None] * tri[:, 2])
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[face]
    return Scatterers(points=pts, normals=normals, amplitude=np.full(count, total / count))


class Occluder:
    """Segment-occlusion queries against a triangle mesh.

    Points go into the caster's own frame once (:meth:`to_frame`), then :meth:`blocked` tests
    segments between such points, which lets the simulator convert each scatterer and sensor
    once instead of once per ray.

    Args:
        mesh: the occluding mesh (metres).
        backend: ``"auto"`` (Embree when trimesh has it, else the pure-trimesh caster),
            ``"embree"`` or ``"triangle"``.
        threads: Embree queries are split over this many threads (Embree releases the GIL);
            None: one per CPU. Results do not depend on it.
    """

    def __init__(self, mesh: trimesh.Trimesh, backend: str = "auto", threads: int | None = None):
        if backend not in ("auto", "embree", "triangle"):
            raise ShsasError(f"unknown ray backend '{backend}' (auto, embree or triangle)")
        if backend == "auto":
            backend = "embree" if trimesh.ray.has_embree else "triangle"
        if backend == "embree" and not trimesh.ray.has_embree:
            raise ShsasError("ray backend 'embree' needs the embreex package (pip install embreex)")
        self.backend = backend
        self.mesh = mesh
        self.threads = max(1, threads or owned_cpus())
        self._pool: ThreadPoolExecutor | None = None
        if backend == "embree":
            from trimesh.ray.ray_pyembree import RayMeshIntersector

            # trimesh's wrapper moves and scales the mesh into a ~100-unit box for float32
            # precision; our queries use the same transform.
            self._wrap = RayMeshIntersector(mesh)._scene
        else:
            from trimesh.ray.ray_triangle import RayMeshIntersector

            self._tri = RayMeshIntersector(mesh)

    def to_frame(self, p: np.ndarray) -> np.ndarray:
        """(R, 3) world points, m -> the caster's frame (float32 scaled box for Embree)."""
        p = np.asarray(p, dtype=np.float64)
        if self.backend == "embree":
            return ((p - self._wrap.origin) * self._wrap.scale).astype(np.float32)
        return p

    def blocked(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Whether each open segment from ``start`` to ``end`` (both (R, 3), in the caster's
        frame, see :meth:`to_frame`) hits the mesh: (R,) bool."""
        r = len(start)
        if r == 0:
            return np.zeros(0, dtype=bool)
        d = end - start
        if self.backend == "embree":
            # the direction is the whole segment, so the segment is t in (0, 1): no normalising
            far = np.ones(r, dtype=np.float32)
            scene = self._wrap.scene
            if self.threads == 1 or r < 20_000:
                res = scene.run(start, d, dists=far, query="OCCLUDED")
            else:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(self.threads)
                cuts = np.linspace(0, r, self.threads + 1).astype(int)
                parts = self._pool.map(
                    lambda ab: scene.run(start[ab[0]:ab[1]], d[ab[0]:ab[1]], dists=far[ab[0]:ab[1]],
                                         query="OCCLUDED"),
                    list(itertools.pairwise(cuts)))
                res = np.concatenate(list(parts))
            # embreex answers OCCLUDED with 0 for a blocked ray and -1 for a free one
            return np.asarray(res) != -1
        length = np.linalg.norm(d, axis=1)
        unit = d / np.maximum(length, 1e-300)[:, None]
        _, ray_idx, locs = self._tri.intersects_id(start, unit, multiple_hits=False,
                                                   return_locations=True)
        out = np.zeros(r, dtype=bool)
        if len(ray_idx):
            dist = np.einsum("ij,ij->i", locs - start[ray_idx], unit[ray_idx])
            out[ray_idx[(dist > 0) & (dist < length[ray_idx])]] = True
        return out

    def occluded(self, origins: np.ndarray, directions: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """Whether each segment ``origin + s·direction``, 0 < s < length, hits the mesh.

        Args:
            origins: (R, 3) segment starts, m.
            directions: (R, 3) unit directions.
            lengths: (R,) segment lengths, m.

        Returns:
            (R,) bool, True where blocked.
        """
        o = np.asarray(origins, dtype=np.float64)
        e = o + np.asarray(directions, dtype=np.float64) * np.asarray(lengths, dtype=np.float64)[:, None]
        return self.blocked(self.to_frame(o), self.to_frame(e))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __del__(self) -> None:
        self.close()
