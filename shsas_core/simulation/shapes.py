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

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import MAX_MESH_ELEMENTS


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


# -- scenes where backprojection is known to fail: thin, lying, concave, shadowed -------------
def _on_floor(m: trimesh.Trimesh) -> trimesh.Trimesh:
    """``m`` moved so that it stands on z = 0, centred on the turntable axis in x and y."""
    lo, hi = m.bounds
    m.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    return m


def tilted_plate() -> trimesh.Trimesh:
    """Thin plate 16 cm x 14 cm x 4 mm, tilted 30° from the floor about the x axis with one long
    edge on the floor: 12.3 cm deep (y) and 7.3 cm high. Two faces 4 mm apart, thinner than a
    range resolution cell of the default pulse (1.7 cm), seen from most sensors at a slant."""
    m = trimesh.creation.box(extents=[0.16, 0.14, 0.004])
    m.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30.0), [1, 0, 0]))
    return _on_floor(m)


def pipe() -> trimesh.Trimesh:
    """A pipe lying on a floor plate: a tube of outer radius 3 cm, wall 4 mm, 18 cm long along
    x, resting on a 24 cm x 24 cm x 5 mm plate (tube axis at z = 3.5 cm). The sidescan case:
    a low object on a strong flat return, open ends to look into."""
    plate = trimesh.creation.box(extents=[0.24, 0.24, 0.005])
    plate.apply_translation([0.0, 0.0, 0.0025])
    tube = trimesh.creation.annulus(r_min=0.026, r_max=0.03, height=0.18, sections=64)
    tube.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))  # axis along x
    tube.apply_translation([0.0, 0.0, 0.005 + 0.03])
    return _on_floor(trimesh.util.concatenate([plate, tube]))


def bowl() -> trimesh.Trimesh:
    """Concave hemispherical bowl, opening up: outer radius 9 cm, wall 5 mm, resting on its
    lowest point; the rim at z = 9 cm. Its inside hides behind the rim from low sensors and
    echoes from several places at once from high ones."""
    ro, ri, n = 0.09, 0.085, 48
    a = np.linspace(-np.pi / 2, 0.0, n)
    inner = np.stack([ri * np.cos(a), ro + ri * np.sin(a)], 1)  # from the bottom up to the rim
    outer = np.stack([ro * np.cos(a[::-1]), ro + ro * np.sin(a[::-1])], 1)  # rim down to the bottom
    profile = np.concatenate([inner, outer])
    profile[[0, -1], 0] = 0.0  # both ends on the axis: the revolved surface is closed
    m = trimesh.creation.revolve(profile, sections=96)
    if m.volume < 0:  # the profile's direction decides the winding
        m.invert()
    return _on_floor(m)


def shadow() -> trimesh.Trimesh:
    """Two objects, one in the other's shadow: a wall 3 cm thick, 16 cm wide (y) and 14 cm high
    at x = -3 cm, and a ball of radius 3 cm on the floor 3 cm behind it (x = 4.5 cm). From the
    sensors on the wall's side the ball is hidden below about 60° of elevation."""
    wall = trimesh.creation.box(extents=[0.03, 0.16, 0.14])
    wall.apply_translation([-0.03, 0.0, 0.07])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    ball.apply_translation([0.045, 0.0, 0.03])
    m = trimesh.util.concatenate([wall, ball])
    m.apply_translation([0.0, 0.0, -m.bounds[0, 2]])
    return m


#: Built-in shapes by name.
SHAPES: dict[str, Callable[[], trimesh.Trimesh]] = {
    "sphere": sphere,
    "cube": cube,
    "torus": torus,
    "scene": scene,
    "plate": tilted_plate,
    "pipe": pipe,
    "bowl": bowl,
    "shadow": shadow,
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
