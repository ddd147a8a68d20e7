"""The azimuth-arc ping subset (shsas_core.trajectory.azimuth_arc_indices)."""

from __future__ import annotations

import numpy as np
import pytest

from shsas_core.trajectory import (
    TrajectoryConfig,
    azimuth_arc_indices,
    azimuth_deg,
    full_trajectory,
)


def test_arc_keeps_exactly_the_half_turn_of_a_circular_trajectory() -> None:
    cfg = TrajectoryConfig(heights=3, angles=120)
    tx, _ = full_trajectory(cfg)
    keep = azimuth_arc_indices(tx, 0.0, 180.0)
    # ping k sits at azimuth 3°·(k mod 120): [0°, 180°) is angle index 0..59, 180° itself is out
    expected = np.flatnonzero(np.arange(len(tx)) % 120 < 60)
    np.testing.assert_array_equal(keep, expected)
    assert keep.dtype == np.int64


def test_arc_wraps_through_zero_and_a_full_circle_keeps_all() -> None:
    tx, _ = full_trajectory(TrajectoryConfig(heights=1, angles=8))  # every 45°
    np.testing.assert_array_equal(azimuth_arc_indices(tx, 270.0, 450.0), [0, 1, 6, 7])
    np.testing.assert_array_equal(azimuth_arc_indices(tx, 90.0, 180.0), [2, 3])
    np.testing.assert_array_equal(azimuth_arc_indices(tx, 10.0, 370.0), np.arange(8))
    np.testing.assert_allclose(azimuth_deg(tx), np.arange(8) * 45.0, atol=1e-9)


@pytest.mark.parametrize("arc", [(0.0, 0.0), (90.0, 45.0), (0.0, 361.0)])
def test_arc_rejects_empty_or_overfull_arcs(arc: tuple[float, float]) -> None:
    with pytest.raises(ValueError, match="arc"):
        azimuth_arc_indices(np.zeros((2, 3)), *arc)
