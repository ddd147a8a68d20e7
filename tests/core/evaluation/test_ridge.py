"""Ridge points of a blurred shell: one sheet at the known ridge radius, normals facing the sensors.

References: the ridge radius of an analytic Gaussian shell (its profile peaks at the shell radius)
and a brute-force loop that tests every voxel along its direction with scipy's spline interpolation;
for the sidelobe suppression a point-by-point loop and an analytic double sheet; for the
visibility vote two closed spheres whose facing halves the nearest sensors see from behind.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from shsas_core.evaluation.ridge import (
    STEEP,
    connected_to_strong,
    derivatives,
    drop_small_pieces,
    orient_toward_sensors,
    ridge,
    suppress_sidelobes,
    visibility_votes,
)
from tests.helpers.voxel_grid import voxel_centres

H = 0.0025
N = 64
LO = np.full(3, -N * H / 2)
R0 = 0.05
C = np.array([0.001, -0.002, 0.0013])  # off the voxel lattice


def centres() -> np.ndarray:
    return voxel_centres(LO, N, H)


def shell(width: float = 0.006) -> np.ndarray:
    r = np.linalg.norm(centres() - C, axis=-1)
    return np.exp(-0.5 * ((r - R0) / width) ** 2).astype(np.float32)


def test_shell_ridge_is_one_sheet_at_the_shell_radius() -> None:
    v = shell()
    r = ridge(v, v > 0.3, LO, np.full(3, H), sigma=1.0)
    d = np.linalg.norm(r.points - C, axis=1)
    # sub-voxel positions: the ridge radius within a tenth of a voxel (smoothing a sphere of
    # radius 20 voxels by 1 voxel moves its ridge by far less)
    assert np.abs(d - R0).max() < 0.1 * H
    # one sheet: about one point per voxel face of area (4πR² / H²), not the shell's thickness
    sheet = 4 * np.pi * R0**2 / H**2
    assert 0.8 * sheet < len(r) < 1.6 * sheet
    assert (v > 0.3).sum() > 3 * sheet  # the thresholded shell is several voxels thick
    # normals across the sheet: radial up to sign
    radial = (r.points - C) / d[:, None]
    assert np.abs(np.einsum("pc,pc->p", r.normals, radial)).min() > 0.99


def test_derivatives_match_scipy_on_a_quadratic() -> None:
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 3))
    a = a + a.T
    b = rng.standard_normal(3)
    x = centres()
    s = 0.5 * np.einsum("...i,ij,...j->...", x, a, x) + x @ b
    idx = rng.integers(1, N - 1, size=(50, 3))
    g, hess = derivatives(s, idx, np.full(3, H))
    xi = x[tuple(idx.T)]
    np.testing.assert_allclose(g, xi @ a + b, atol=1e-9)  # central differences are exact on quadratics
    np.testing.assert_allclose(hess, np.broadcast_to(a, hess.shape), atol=1e-6)
    # and against scipy's own gradient of the same samples
    ref = np.stack(np.gradient(s, H, H, H), -1)[tuple(idx.T)]
    np.testing.assert_allclose(g, ref, atol=1e-9)


def test_ridge_voxels_match_a_brute_force_line_search() -> None:
    # an ellipsoidal shell (three different curvatures); every candidate voxel is tested by a
    # loop that samples the smoothed volume along the voxel's normal with cubic splines and asks
    # whether the maximum of that 1-D profile lies within half a voxel of the centre (with the
    # module's two curvature conditions, the gradient taken by numpy)
    x = centres()
    q = np.linalg.norm((x - C) / np.array([1.0, 0.8, 0.6]), axis=-1)
    v = np.exp(-0.5 * ((q - 0.045) / 0.005) ** 2).astype(np.float32)
    cand = v > 0.5
    r = ridge(v, cand, LO, np.full(3, H), sigma=1.0)
    s = ndimage.gaussian_filter(v, 1.0, mode="nearest").astype(np.float64)
    coef = ndimage.spline_filter(s, order=3, mode="nearest")
    ts = np.linspace(-1.5, 1.5, 301)  # voxels along the normal
    found = {tuple(i) for i in r.index}
    idx = np.argwhere(cand)
    _, hess = derivatives(s.astype(np.float32), idx, np.full(3, H))
    agree = 0
    lams, vecs = np.linalg.eigh(hess)
    grad = np.stack(np.gradient(s, H, H, H), -1)
    for k, i in enumerate(idx):
        lam, n = lams[k], vecs[k][:, 0]
        pts = i[:, None] + n[:, None] * ts[None, :]
        prof = ndimage.map_coordinates(coef, pts, order=3, mode="nearest", prefilter=False)
        peak = ts[np.argmax(prof)]
        flank = np.linalg.norm(grad[tuple(i)]) > -lam[0] * STEEP * H or -lam[0] < abs(lam[2])
        brute = lam[0] < 0 and not flank and abs(peak) <= 0.5 and 0 < np.argmax(prof) < len(ts) - 1
        agree += brute == (tuple(i) in found)
    # the quadratic model and the spline line search disagree only at the slab edges
    assert agree / len(idx) > 0.97


def test_pieces_and_hysteresis() -> None:
    v = shell()
    r = ridge(v, v > 0.3, LO, np.full(3, H), sigma=1.0)
    # a speck far from the shell
    speck = np.zeros_like(v)
    speck[5, 5, 5] = 1.0
    rs = ridge(speck, speck > 0.5, LO, np.full(3, H), sigma=1.0)
    assert len(rs) == 1
    both = type(r)(np.concatenate([r.index, rs.index]), np.concatenate([r.points, rs.points]),
                   np.concatenate([r.normals, rs.normals]), np.concatenate([r.values, np.float32([0.2])]))
    kept = drop_small_pieces(both, v.shape, 0.01)
    assert len(kept) == len(r)
    # hysteresis: the speck (value 0.2) has no strong voxel in its piece, the shell has
    strong = connected_to_strong(both, v.shape, 0.5)
    assert len(strong) == len(r)


def test_normals_face_the_sensors_around_an_object() -> None:
    rng = np.random.default_rng(1)
    p = rng.standard_normal((2000, 3))
    out = p / np.linalg.norm(p, axis=1, keepdims=True)
    pts = 0.05 * out
    flipped = out * rng.choice([-1.0, 1.0], size=(2000, 1))
    ang = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    rings = [np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(90, z)], 1) for z in (-0.4, 0.0, 0.4)]
    n = orient_toward_sensors(pts, flipped, np.concatenate(rings))
    assert np.all(np.einsum("pc,pc->p", n, out) > 0)


def suppressed_by_loop(points: np.ndarray, normals: np.ndarray, strength: np.ndarray, reach: float, gap: float,
                       width: float) -> np.ndarray:
    """The sidelobe rule point by point: dropped when some stronger point's normal line passes
    within ``width`` of it at a distance in [gap, reach] in front of it (along its normal)."""
    keep = np.ones(len(points), dtype=bool)
    for i in range(len(points)):
        for j in range(len(points)):
            if strength[j] <= strength[i]:
                continue
            d = points[i] - points[j]
            along = float(d @ normals[j])
            across = float(np.linalg.norm(d - along * normals[j]))
            if gap <= along <= reach and across <= width:
                keep[i] = False
                break
    return keep


def test_sidelobe_suppression_matches_a_brute_force_loop() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.02, 0.02, (300, 3))
    nrm = rng.standard_normal((300, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    strength = rng.uniform(0, 1, 300)
    got = suppress_sidelobes(pts, nrm, strength, reach=0.0086, gap=0.0025, width=0.004)
    want = suppressed_by_loop(pts, nrm, strength, reach=0.0086, gap=0.0025, width=0.004)
    assert 0 < (~want).sum() < len(pts)  # the draw exercises both outcomes
    np.testing.assert_array_equal(got, want)


def double_sheet(apart: float, second: float) -> np.ndarray:
    """A bright plane z = 0 and a weaker parallel one ``apart`` m above it (``second`` of its
    peak), each a Gaussian profile of 2 mm across, over a 10 cm square."""
    c = centres()
    inside = np.all(np.abs(c[..., :2]) < 0.05, axis=-1)
    z = c[..., 2] - 0.0003  # off the voxel lattice
    prof = np.exp(-0.5 * (z / 0.002) ** 2) + second * np.exp(-0.5 * ((z - apart) / 0.002) ** 2)
    return (prof * inside).astype(np.float32)


def kept_sheet_shares(apart: float, lit_from: float) -> tuple[float, float]:
    """Shares of the bright sheet's and the weaker sheet's ridge points kept, the surface lit from
    above (``lit_from`` = +1) or below (-1)."""
    v = double_sheet(apart, 0.5)
    r = ridge(v, v > 0.2, LO, np.full(3, H), sigma=0.5)
    z = r.points[:, 2]
    main, side = np.abs(z) < H, np.abs(z - apart) < H
    assert main.sum() > 1000 and side.sum() > 1000  # the ridge finds both sheets
    up = lit_from * np.sign(r.normals[:, 2:3])  # the normals face the sensors
    keep = suppress_sidelobes(r.points, r.normals * up, v[tuple(r.index.T)], reach=0.0086, gap=H, width=H)
    return float(keep[main].mean()), float(keep[side].mean())


def test_a_double_sheet_keeps_the_main_sheet_only() -> None:
    # a weaker sheet 7.5 mm in front of a bright one, under the 8.6 mm range resolution: its sidelobe
    main, side = kept_sheet_shares(0.0075, +1.0)
    assert main > 0.99 and side < 0.02
    # the same sheet behind the bright one (the far face of a thin part) stays
    main, side = kept_sheet_shares(0.0075, -1.0)
    assert main > 0.99 and side > 0.99
    # beyond the range resolution a second sheet is a second surface, and stays
    main, side = kept_sheet_shares(0.012, +1.0)
    assert main > 0.99 and side > 0.99


def two_closed_spheres() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two hollow spheres (2.5 cm radius, centres at x = ±4 cm) as bright voxel shells, and the
    points of each one's half that faces the other with their outward normals."""
    c = centres()
    occupied = np.zeros(c.shape[:3], dtype=bool)
    pts, nrm = [], []
    for cx in (-0.04, 0.04):
        centre = np.array([cx, 0.0, 0.0])
        occupied |= np.abs(np.linalg.norm(c - centre, axis=-1) - 0.025) < H
        d = np.random.default_rng(0).standard_normal((400, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d = d[d[:, 0] * -np.sign(cx) > 0.7]  # facing the other sphere, toward the survey's axis
        pts.append(centre + 0.025 * d)
        nrm.append(d)
    return occupied, np.concatenate(pts), np.concatenate(nrm)


def test_visibility_orients_faces_turned_toward_the_axis() -> None:
    occupied, pts, out = two_closed_spheres()
    ang = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    rings = np.concatenate([np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(90, z)], 1)
                            for z in (0.05, 0.2, 0.4)])
    flip = np.random.default_rng(2).choice([-1.0, 1.0], size=(len(pts), 1))
    # the nearest sensors lie behind these faces: that vote alone turns most of them inward
    nearest = orient_toward_sensors(pts, out * flip, rings, rounds=0)
    assert np.mean(np.einsum("pc,pc->p", nearest, out) < 0) > 0.5
    votes = visibility_votes(pts, out * flip, rings, occupied, LO, np.full(3, H), own_cell=0.0086)
    assert np.all(votes * flip[:, 0] > 0)  # each vote picks the outward side
    n = orient_toward_sensors(pts, out * flip, rings, votes=votes)
    assert np.mean(np.einsum("pc,pc->p", n, out) > 0) > 0.99
