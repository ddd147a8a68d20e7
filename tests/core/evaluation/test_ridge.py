"""Ridge points of a blurred shell: one sheet at the known ridge radius, normals facing the sensors.

References: the ridge radius of an analytic Gaussian shell (its profile peaks at the shell radius)
and a brute-force loop that tests every voxel along its direction with scipy's spline interpolation.
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
)

H = 0.0025
N = 64
LO = np.full(3, -N * H / 2)
R0 = 0.05
C = np.array([0.001, -0.002, 0.0013])  # off the voxel lattice


def centres() -> np.ndarray:
    ax = LO[0] + (np.arange(N) + 0.5) * H
    return np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)


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
