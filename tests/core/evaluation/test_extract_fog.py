"""The fog step of the ridge extraction (``extract.without_fog``, a candidate, off by default): a
neural field's faint sheets in empty space go, a surface's dim flank stays, and a ridge with no
fog is left alone.

Reference: a shell whose brightness falls along it from the top (1.0) to its lower flank (0.3),
plus faint flat sheets (0.08-0.14) away from it; which voxel belongs to which is known by
construction, and the expected result is worked out point by point from the rule's statement.
"""

from __future__ import annotations

import numpy as np

from shsas_core.evaluation.extract import ExtractConfig, otsu_threshold, without_fog
from shsas_core.evaluation.ridge import ridge
from tests.helpers.voxel_grid import voxel_centres

H = 0.0025
N = 64
LO = np.full(3, -N * H / 2)
R0 = 0.04
C = np.array([0.001, -0.002, 0.0013])


def centres() -> np.ndarray:
    return voxel_centres(LO, N, H)


def shell_with_dim_flank() -> np.ndarray:
    """A Gaussian shell of radius R0 whose peak falls from 1.0 at its top to 0.3 at its bottom."""
    x = centres()
    r = np.linalg.norm(x - C, axis=-1)
    cos_el = np.clip((x[..., 2] - C[2]) / np.maximum(r, 1e-9), -1, 1)
    peak = 0.3 + 0.7 * (1 + cos_el) / 2
    return (peak * np.exp(-0.5 * ((r - R0) / 0.005) ** 2)).astype(np.float32)


def faint_sheets() -> tuple[np.ndarray, np.ndarray]:
    """Flat faint sheets in the box's corners, away from the shell: (magnitude, which voxels)."""
    x = centres()
    v = np.zeros(x.shape[:3], dtype=np.float32)
    where = np.zeros(x.shape[:3], dtype=bool)
    for k, (cx, cy, level) in enumerate([(-0.065, -0.065, 0.08), (0.065, 0.065, 0.11), (-0.065, 0.065, 0.14)]):
        z0 = -0.05 + 0.03 * k
        across = np.exp(-0.5 * ((x[..., 2] - z0) / 0.004) ** 2)
        inside = (np.abs(x[..., 0] - cx) < 0.012) & (np.abs(x[..., 1] - cy) < 0.012)
        v = np.maximum(v, np.where(inside, level * across, 0).astype(np.float32))
        where |= inside & (np.abs(x[..., 2] - z0) < 0.01)
    return v, where


def ridge_of(v: np.ndarray):
    return ridge(v, v > 0.03, LO, np.full(3, H), sigma=1.0)


def test_faint_sheets_go_and_the_dim_flank_stays() -> None:
    shell = shell_with_dim_flank()
    fog, fog_voxels = faint_sheets()
    v = np.maximum(shell, fog)
    r = ridge_of(v)
    mags = v[tuple(r.index.T)]
    is_fog = fog_voxels[tuple(r.index.T)]
    tau = 0.15
    assert is_fog.mean() > 0.05 and np.all(mags[is_fog] < tau)  # the case the step is for
    assert mags[~is_fog].min() < otsu_threshold(mags) < mags[~is_fog].max()  # a dim flank below the split
    kept = without_fog(r, v, tau, 0.05)
    kept_keys = {tuple(i) for i in kept.index}
    for i, m, f in zip(r.index, mags, is_fog, strict=True):
        # the rule, point by point: the shell is one piece holding its bright top, the sheets
        # lie below τ
        assert (tuple(i) in kept_keys) == (not f and m >= tau)
    # the flank below Otsu's split but above τ stays with its bright top
    assert np.any(v[tuple(kept.index.T)] < otsu_threshold(mags))


def test_a_ridge_without_fog_is_left_alone() -> None:
    v = shell_with_dim_flank()
    r = ridge_of(v)
    tau = 0.5 * float(v[tuple(r.index.T)].min())  # every ridge point above τ: no fog
    kept = without_fog(r, v, tau, 0.05)
    assert kept is r


def test_a_separate_bright_object_is_kept_and_fog_share_one_turns_the_step_off() -> None:
    shell = shell_with_dim_flank()
    fog, _ = faint_sheets()
    # a second, separate object as bright as the shell's top: a piece of its own that reaches the split
    x = centres()
    blob = np.exp(-0.5 * (np.linalg.norm(x - np.array([0.06, -0.06, 0.05]), axis=-1) / 0.004) ** 2)
    v = np.maximum(np.maximum(shell, fog), blob.astype(np.float32))
    r = ridge_of(v)
    blob_points = (np.linalg.norm(r.points - np.array([0.06, -0.06, 0.05]), axis=1) < 0.01) & (
        v[tuple(r.index.T)] >= 0.15)
    assert blob_points.any()
    kept = without_fog(r, v, 0.15, 0.05)
    kept_keys = {tuple(i) for i in kept.index}
    assert all(tuple(i) in kept_keys for i in r.index[blob_points])
    assert without_fog(r, v, 0.15, 1.0) is r


def test_the_fog_step_is_off_by_default_and_on_with_a_share() -> None:
    from shsas_core.data.volume import Grid, Volume
    from shsas_core.evaluation.extract import ridge_cloud

    fog, _ = faint_sheets()
    v = np.maximum(shell_with_dim_flank(), fog)
    vol = Volume(Grid(tuple(LO), tuple(LO + N * H), (N, N, N)), v)
    far = lambda c: np.abs(np.linalg.norm(c.points - C, axis=1) - R0) > 0.015  # noqa: E731
    tau = 0.15
    # the fog step alone (the bright-pieces step, on by default, off)
    as_image = ridge_cloud(vol, tau, ExtractConfig(piece_level=None))
    as_field = ridge_cloud(vol, tau, ExtractConfig(fog_share=0.05, piece_level=None))
    assert far(as_image).sum() > 0.05 * len(as_image)  # the sheets pass the contrast test
    assert far(as_field).sum() == 0
    assert len(as_field) > 0.9 * (~far(as_image)).sum()
    # the default's bright-pieces step drops the sheets too and keeps the dim flank
    default = ridge_cloud(vol, tau, ExtractConfig())
    assert far(default).sum() == 0
    assert len(default) > 0.9 * (~far(as_image)).sum()
