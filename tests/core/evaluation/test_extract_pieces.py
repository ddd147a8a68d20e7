"""The pieces steps of the ridge extraction: bright pieces (``ExtractConfig.piece_level``,
``piece_reach``): a dim piece of ridge far from the object goes, a dim piece within reach of it
stays, and with the step off both stay; specks (``min_piece``, with the same reach): small pieces
within reach of the object's sheet stay, a small piece apart from it goes.

Reference: a bright Gaussian shell plus dim flat patches, 13 mm outside the shell (within two
range resolutions of 8.6 mm) and in the box's corner (5 cm and more from the shell); which ridge
point belongs to which is known by construction. The reach itself is checked against a
brute-force loop over the pieces' pairwise distances.
"""

from __future__ import annotations

import numpy as np

from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.extract import ExtractConfig, ridge_cloud
from shsas_core.evaluation.ridge import Ridge, connected_to_strong, piece_labels
from tests.helpers.voxel_grid import voxel_centres

H = 0.0025
N = 64
LO = np.full(3, -N * H / 2)
R0 = 0.035
RES = 0.0086  # the survey's range resolution c/2B, m
C = np.array([0.001, -0.002, 0.0013])
#: The patches: (centre x, y, z of the sheet, peak); the first 13 mm outside the shell's top.
NEAR = (C[0], C[1], C[2] + R0 + 0.013, 0.5)
FAR = (-0.06, -0.06, -0.06, 0.3)


def centres() -> np.ndarray:
    return voxel_centres(LO, N, H)


def shell_with_patches(patches) -> Volume:
    """The shell (peak 1) and flat patches across z, each ``((x, y, z, peak), half width m)``."""
    x = centres()
    r = np.linalg.norm(x - C, axis=-1)
    v = np.exp(-0.5 * ((r - R0) / 0.004) ** 2)
    for (cx, cy, cz, peak), half in patches:
        inside = (np.abs(x[..., 0] - cx) < half) & (np.abs(x[..., 1] - cy) < half)
        v = np.maximum(v, np.where(inside, peak * np.exp(-0.5 * ((x[..., 2] - cz) / 0.003) ** 2), 0.0))
    box = SceneBox(min=tuple(LO), max=tuple(LO + N * H))
    # non-zero everywhere: the whole box is estimated
    return Volume(Grid.over(box, N), (v + 1e-6).astype(np.float32))


def cloud(config: ExtractConfig):
    """The ridge of the shell and the two 2 cm patches (peaks 0.5 and 0.3)."""
    return ridge_cloud(shell_with_patches(((NEAR, 0.01), (FAR, 0.01))), 0.2, config, resolution=RES)


def near_patch(points: np.ndarray, patch: tuple[float, float, float, float]) -> np.ndarray:
    cx, cy, cz, _ = patch
    return (np.abs(points[:, 0] - cx) < 0.012) & (np.abs(points[:, 1] - cy) < 0.012) & (np.abs(points[:, 2] - cz) < 0.005)


def test_the_far_dim_piece_goes_and_the_near_one_stays() -> None:
    on = cloud(ExtractConfig()).points
    off = cloud(ExtractConfig(piece_level=None)).points
    # without the step both patches pass the contrast test (the box around them is empty)
    assert near_patch(off, FAR).sum() > 20
    assert near_patch(off, NEAR).sum() > 20
    assert near_patch(on, FAR).sum() == 0
    assert near_patch(on, NEAR).sum() == near_patch(off, NEAR).sum()
    shell = np.abs(np.linalg.norm(on - C, axis=1) - R0) < 0.003
    assert shell.sum() == (np.abs(np.linalg.norm(off - C, axis=1) - R0) < 0.003).sum()
    # no reach: the near patch, dim and apart from the shell's ridge, goes too
    assert near_patch(cloud(ExtractConfig(piece_reach=0)).points, NEAR).sum() == 0


def reach_by_loop(r: Ridge, shape: tuple[int, int, int], strong: float, reach: float) -> np.ndarray:
    lab, count = piece_labels(r, shape)
    bright = {int(p) for p in np.unique(lab[r.values >= strong])}
    keep = np.zeros(len(r), dtype=bool)
    for p in range(1, count + 1):
        mine = lab == p
        if p in bright:
            keep |= mine
            continue
        for q in bright:
            d = np.linalg.norm(r.points[mine][:, None, :] - r.points[lab == q][None, :, :], axis=-1)
            if d.min() <= reach:
                keep |= mine
                break
    return keep


def test_reach_matches_a_loop_over_pieces() -> None:
    rng = np.random.default_rng(3)
    shape = (40, 40, 40)
    index = np.unique(rng.integers(0, 40, size=(300, 3)), axis=0)
    points = LO + (index + rng.uniform(0, 1, index.shape)) * H
    values = rng.uniform(0, 1, len(index)).astype(np.float32)
    r = Ridge(index, points, np.tile([0.0, 0.0, 1.0], (len(index), 1)), values)
    for reach in (0.0, 2 * H, 5 * H):
        kept = connected_to_strong(r, shape, 0.9, reach=reach)
        expected = reach_by_loop(r, shape, 0.9, reach)
        assert 0 < expected.sum() < len(r)
        assert sorted(map(tuple, kept.index)) == sorted(map(tuple, index[expected]))


#: Small pieces (centre x, y, z, peak): four 5 mm squares 13 mm outside the shell's top, apart
#: from each other (a surface lit at grazing angles, broken into fragments), and one voxel column in the
#: box's corner.
FRAGMENTS = tuple((C[0] + dx, C[1] + dy, C[2] + R0 + 0.013, 0.5) for dx, dy in
                  ((-0.012, -0.012), (-0.012, 0.012), (0.012, -0.012), (0.012, 0.012)))
SPECK = (-0.06125, -0.06125, -0.06, 1.0)  # on a column of voxel centres


def on_piece(points: np.ndarray, piece: tuple[float, float, float, float]) -> np.ndarray:
    return np.all(np.abs(points - np.asarray(piece[:3])) < 0.005, axis=1)


def test_fragments_by_the_object_stay_and_a_speck_apart_goes() -> None:
    vol = shell_with_patches((*((f, 0.0025) for f in FRAGMENTS), (SPECK, 0.001)))
    kept = ridge_cloud(vol, 0.2, ExtractConfig(), resolution=RES).points
    unfiltered = ridge_cloud(vol, 0.2, ExtractConfig(min_piece=0), resolution=RES).points
    shell = (np.abs(np.linalg.norm(unfiltered - C, axis=1) - R0) < 0.003).sum()
    for patch in (*FRAGMENTS, SPECK):
        # each is a speck by size: under min_piece's share of the shell's ridge
        assert 0 < on_piece(unfiltered, patch).sum() < ExtractConfig().min_piece * shell
    for patch in FRAGMENTS:
        assert on_piece(kept, patch).sum() == on_piece(unfiltered, patch).sum()
    assert on_piece(kept, SPECK).sum() == 0
    # no reach: the fragments are specks too
    alone = ridge_cloud(vol, 0.2, ExtractConfig(piece_reach=0), resolution=RES).points
    assert all(on_piece(alone, patch).sum() == 0 for patch in FRAGMENTS)
