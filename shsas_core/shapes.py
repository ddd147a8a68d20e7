"""Built-in test meshes and mesh loading.

Every built-in shape is in metres, z up, standing on z = 0 and centred on the turntable axis,
sized like the AirSAS turntable objects: it fits inside x, y in [-0.125, 0.125] and z in
[0, 0.2] (the typical reconstruction box of ``docs/formats.md``).

``load_mesh`` takes either one of those names or a path to an OBJ/PLY/STL/GLB/OFF file; a GLB
or OBJ holding several parts (a scene) is concatenated into one mesh.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from .errors import ShsasError
from .survey import MAX_MESH_ELEMENTS


def sphere() -> trimesh.Trimesh:
    """Sphere of radius 8 cm resting on the floor (centre at z = 0.08 m); 2,562 vertices."""
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.08)
    m.apply_translation([0.0, 0.0, 0.08])
    return m


def cube() -> trimesh.Trimesh:
    """Axis-aligned cube with 15 cm sides on the floor, rotated 30° about z so that no face
    looks straight along a sensor axis (12 triangles)."""
    m = trimesh.creation.box(extents=[0.15, 0.15, 0.15])
    m.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30.0), [0, 0, 1]))
    m.apply_translation([0.0, 0.0, 0.075])
    return m


def torus() -> trimesh.Trimesh:
    """Upright torus (ring in the x-z plane, hole along y): major radius 7 cm, tube radius
    2.5 cm, touching the floor; it occludes itself and has a hole to see through."""
    m = trimesh.creation.torus(major_radius=0.07, minor_radius=0.025,
                               major_sections=64, minor_sections=32)
    # trimesh builds the ring in the x-y plane; stand it up about x
    m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    m.apply_translation([0.0, 0.0, 0.095])
    return m


def scene() -> trimesh.Trimesh:
    """Several separate primitives on the floor: a box, a sphere, an upright cylinder and a
    cone, arranged so that they partly hide each other from low sensor heights."""
    parts = []
    box = trimesh.creation.box(extents=[0.07, 0.05, 0.06])
    box.apply_transform(trimesh.transformations.rotation_matrix(np.radians(20.0), [0, 0, 1]))
    box.apply_translation([-0.06, -0.055, 0.03])
    parts.append(box)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    ball.apply_translation([0.06, 0.055, 0.04])
    parts.append(ball)
    cyl = trimesh.creation.cylinder(radius=0.025, height=0.16, sections=48)
    cyl.apply_translation([0.055, -0.06, 0.08])
    parts.append(cyl)
    cone = trimesh.creation.cone(radius=0.035, height=0.09, sections=48)
    cone.apply_translation([-0.06, 0.06, 0.0])
    parts.append(cone)
    return trimesh.util.concatenate(parts)


#: Built-in shapes by name.
SHAPES: dict[str, Callable[[], trimesh.Trimesh]] = {
    "sphere": sphere,
    "cube": cube,
    "torus": torus,
    "scene": scene,
}


def shape(name: str) -> trimesh.Trimesh:
    """A built-in mesh by name (see :data:`SHAPES`); raises ShsasError for an unknown name."""
    try:
        build = SHAPES[name.lower()]
    except KeyError:
        raise ShsasError(f"unknown shape '{name}' (choose one of: {', '.join(SHAPES)})") from None
    return build()


def load_mesh(path_or_name: str | os.PathLike) -> trimesh.Trimesh:
    """Load a triangle mesh from a file, or build a built-in shape by name.

    Args:
        path_or_name: a name in :data:`SHAPES` or a path to a mesh file (OBJ, PLY, STL, OFF,
            GLB/GLTF; multi-part files are concatenated into one mesh). Coordinates are taken
            as metres, z up.

    Returns:
        The mesh (float64 vertices (V, 3), int64 faces (F, 3)), F >= 1.

    Raises:
        ShsasError: unknown name, missing or unreadable file, no triangles, non-finite vertices
            or more elements than the survey limit.
    """
    text = os.fspath(path_or_name)
    if text.lower() in SHAPES and not Path(text).exists():
        return shape(text)
    path = Path(text)
    if not path.exists():
        raise ShsasError(f"mesh '{text}' not found (give a mesh file or one of: {', '.join(SHAPES)})")
    if not path.is_file():
        raise ShsasError(f"mesh '{text}' is not a file")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for bad files
        raise ShsasError(f"cannot read mesh '{text}': {type(exc).__name__}: {exc}"[:300]) from None
    if isinstance(loaded, trimesh.Scene):  # force="mesh" yields a Scene only when empty
        geoms = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geoms) if geoms else trimesh.Trimesh()
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ShsasError(f"mesh '{text}' holds no triangles")
    check_mesh(loaded, text)
    return loaded


def check_mesh(mesh: trimesh.Trimesh, what: str = "mesh") -> None:
    """Raise ShsasError when ``mesh`` is empty, too large or has non-finite vertices."""
    if len(mesh.faces) == 0:
        raise ShsasError(f"{what} holds no triangles")
    if len(mesh.vertices) + len(mesh.faces) > MAX_MESH_ELEMENTS:
        raise ShsasError(f"{what} has {len(mesh.faces)} faces, above the limit of {MAX_MESH_ELEMENTS}")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ShsasError(f"{what} has non-finite vertex coordinates")
    if mesh.area <= 0:
        raise ShsasError(f"{what} has zero surface area")
