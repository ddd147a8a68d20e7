import numpy as np

from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import Grid, Volume


def test_grid_cubic_voxels_cover_box():
    g = Grid.over(SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2)), 20)
    assert g.shape == (20, 20, 20)
    np.testing.assert_allclose(g.spacing, 0.01)
    p = g.points()
    assert p.shape == (8000, 3)
    np.testing.assert_allclose(p[0], [-0.095, -0.095, 0.005])
    np.testing.assert_allclose(p[1], [-0.095, -0.095, 0.015])  # z fastest


def test_volume_normalized():
    g = Grid((0, 0, 0), (1, 1, 1), (2, 2, 2))
    v = Volume(g, np.arange(8, dtype=np.complex64).reshape(2, 2, 2) * 1j)
    assert v.normalized().max() == 1.0
