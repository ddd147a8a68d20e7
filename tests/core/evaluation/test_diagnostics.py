"""Checks for failed results: collapsed and box-filling volumes, fits whose loss did not fall."""

import numpy as np
import pytest

from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.diagnostics import (
    BOX_FILL_LIMIT,
    COLLAPSE_SPREAD_LIMIT,
    LOSS_EXPLAINED,
    LOSS_MIN_ITERS,
    LOSS_RATIO_LIMIT,
    SURFACE_KEPT_LIMIT,
    ResultWarning,
    fit_warnings,
    loss_limit,
    loss_ratio,
    loss_windows,
    surface_kept_share,
    volume_warnings,
)
from shsas_core.evaluation.extract import choose_threshold, extract

#: The built-in sphere's scene box (r = 8 cm sphere on z = 0, 2 cm margin), 32³ voxels.
GRID = Grid((-0.1, -0.1, -0.02), (0.1, 0.1, 0.18), (32, 32, 32))


def checked(values: np.ndarray) -> list[ResultWarning]:
    """Extract like the pipeline does (default Otsu rule), then check."""
    vol = Volume(GRID, values.astype(np.float32))
    tau, _cloud, _ = extract(vol)
    return volume_warnings(vol, tau)


def shell(radius: float = 0.08, width: float = 0.006, floor: float = 0.01, seed: int = 0) -> np.ndarray:
    """A Gaussian shell on the sphere's surface over a weak noise floor (what a good fit looks like)."""
    r = np.linalg.norm(GRID.points() - [0.0, 0.0, 0.0], axis=1).reshape(GRID.shape)
    rng = np.random.default_rng(seed)
    return np.exp(-0.5 * ((r - radius) / width) ** 2) + floor * rng.random(GRID.shape)


def test_a_surface_shell_raises_nothing() -> None:
    assert checked(shell()) == []


@pytest.mark.parametrize("values", [np.zeros(GRID.shape), np.full(GRID.shape, 0.37),
                                    0.37 + 1e-6 * np.random.default_rng(1).random(GRID.shape),
                                    # a freshly initialised neural field: flat to ~0.3 % (measured 0.0028)
                                    0.0089 * (1 + 0.003 * np.random.default_rng(1).random(GRID.shape))],
                         ids=["zeros", "constant", "constant+rounding", "untrained-field"])
def test_a_constant_volume_is_collapsed(values: np.ndarray) -> None:
    found = checked(values)
    assert [w.code for w in found] == ["collapsed"]
    assert found[0].measure < COLLAPSE_SPREAD_LIMIT == found[0].limit


def test_an_untrained_field_inside_an_occupancy_mask_is_collapsed() -> None:
    # a masked field is exactly 0 outside its mask: the step at the mask's edge is not a reconstruction
    inside = np.linalg.norm(GRID.points(), axis=1).reshape(GRID.shape) < 0.09
    values = np.where(inside, 0.0089 * (1 + 0.003 * np.random.default_rng(4).random(GRID.shape)), 0.0)
    found = checked(values)
    assert [w.code for w in found] == ["collapsed"]
    assert found[0].measure < COLLAPSE_SPREAD_LIMIT


def test_a_shell_inside_an_occupancy_mask_is_not_collapsed() -> None:
    inside = np.linalg.norm(GRID.points(), axis=1).reshape(GRID.shape) < 0.09
    assert checked(np.where(inside, shell(), 0.0)) == []


def test_complex_volumes_are_checked_by_magnitude() -> None:
    # a constant magnitude under a varying phase is still nothing
    phase = np.exp(1j * np.random.default_rng(2).uniform(0, 2 * np.pi, GRID.shape))
    vol = Volume(GRID, (0.5 * phase).astype(np.complex64))
    assert [w.code for w in volume_warnings(vol, 0.5)] == ["collapsed"]


def test_a_volume_with_60_percent_above_tau_fills_the_box() -> None:
    rng = np.random.default_rng(3)
    values = np.where(rng.random(GRID.shape) < 0.6, 1.0, 0.1) + 0.01 * rng.random(GRID.shape)
    found = checked(values)
    assert [w.code for w in found] == ["box_filling"]
    assert found[0].measure == pytest.approx(0.6, abs=0.02) and found[0].limit == BOX_FILL_LIMIT
    assert "fills the scene box" in found[0].message


def test_box_filling_counts_the_voxels_at_or_above_tau() -> None:
    # a ramp along x: the share of voxels at or above τ is known exactly for each τ
    x = (np.arange(GRID.shape[0]) + 0.5) / GRID.shape[0]
    vol = Volume(GRID, np.broadcast_to(x[:, None, None], GRID.shape).astype(np.float32).copy())
    norm_x = (x - x[0]) / (x[-1] - x[0])
    for tau in (0.3, 0.5, 0.7):
        share = float(np.mean(norm_x >= tau))
        found = volume_warnings(vol, tau)
        assert [w.code for w in found] == (["box_filling"] if share >= BOX_FILL_LIMIT else [])
        if found:
            assert found[0].measure == pytest.approx(share)


#: A finer grid than GRID, so that sheets 2 cm apart survive the ridge's smoothing.
FINE = Grid((-0.1, -0.1, -0.02), (0.1, 0.1, 0.18), (64, 64, 64))
#: The survey's range resolution the extraction smooths at, m (the default band's c / 2B).
RESOLUTION = 0.0086


def sheets(clutter: float) -> Volume:
    """A bright sheet at x = 0 among parallel sheets of brightness ``clutter`` every 2 cm (the
    lobes of an undersampled aperture): a clutter sheet is about twice the mean of its window,
    below the surface test's contrast of 2.5, and at 0.3 above Otsu's level."""
    x = FINE.points()[:, 0].reshape(FINE.shape)
    stripes = np.exp(-0.5 * ((np.mod(x + 0.01, 0.02) - 0.01) / 0.004) ** 2)
    bright = np.exp(-0.5 * (x / 0.002) ** 2)
    values = np.maximum(bright, clutter * stripes) + 0.01 * np.random.default_rng(0).random(FINE.shape)
    return Volume(FINE, values.astype(np.float32))


def test_a_surface_test_that_keeps_little_of_the_ridge_is_reported() -> None:
    vol = sheets(0.3)
    tau, cloud, _ = extract(vol, resolution=RESOLUTION)
    kept = surface_kept_share(vol, tau, len(cloud), RESOLUTION)
    assert kept < SURFACE_KEPT_LIMIT
    found = volume_warnings(vol, tau, len(cloud), RESOLUTION)
    assert [w.code for w in found] == ["surface_unclear"]
    assert found[0].measure == pytest.approx(kept)
    assert str(len(cloud)) in found[0].message and "9 mm" in found[0].message


@pytest.mark.parametrize("clutter", [0.0, 0.2])
def test_a_clear_sheet_is_not_reported(clutter: float) -> None:
    """Without clutter, or with clutter below τ (which the ridge at τ does not hold either)."""
    vol = sheets(clutter)
    tau, cloud, _ = extract(vol, resolution=RESOLUTION)
    assert surface_kept_share(vol, tau, len(cloud), RESOLUTION) >= SURFACE_KEPT_LIMIT
    assert volume_warnings(vol, tau, len(cloud), RESOLUTION) == []


def test_a_threshold_cloud_has_no_surface_test_to_judge() -> None:
    vol = sheets(0.3)
    assert volume_warnings(vol, choose_threshold(vol), None, RESOLUTION) == []


def test_a_falling_loss_raises_nothing() -> None:
    rng = np.random.default_rng(4)
    it = np.arange(300)
    loss = (0.3 + 0.7 * np.exp(-it / 60)) * (1 + 0.3 * rng.standard_normal(300))
    assert loss_ratio(loss)[0] < LOSS_RATIO_LIMIT
    assert fit_warnings(loss.tolist()) == []


def test_a_flat_loss_is_not_falling() -> None:
    rng = np.random.default_rng(5)
    loss = 1.0 + 0.3 * rng.standard_normal(300)  # batch noise around "predicting zeros"
    found = fit_warnings(loss.tolist())
    assert [w.code for w in found] == ["loss_not_falling"]
    assert found[0].measure >= found[0].limit and found[0].limit <= LOSS_RATIO_LIMIT
    # a rising loss too
    assert [w.code for w in fit_warnings(np.linspace(0.5, 1.0, 100).tolist())] == ["loss_not_falling"]


def test_a_flat_loss_after_a_warm_start_is_no_failure() -> None:
    # a warm-started fit on a noisy survey: the field explains most of the data from the start
    # (data loss ~0.16, batch noise as large as the mean) and the fit takes little more
    rng = np.random.default_rng(8)
    loss = np.linspace(0.16, 0.155, 2000) * rng.lognormal(-0.3, 0.75, 2000)
    ratio, se = loss_ratio(loss)
    assert loss_windows(loss)[0].mean() < LOSS_EXPLAINED and ratio >= loss_limit(se)  # the fall rule's verdict
    assert fit_warnings(loss.tolist()) == []


def test_a_rise_after_a_warm_start_is_reported() -> None:
    rng = np.random.default_rng(9)
    loss = np.linspace(0.15, 0.4, 500) * (1 + 0.3 * rng.standard_normal(500))
    (found,) = fit_warnings(loss.tolist())
    assert found.code == "loss_not_falling" and "rose" in found.message
    assert found.measure > found.limit > 1.0


def test_a_fall_within_the_noise_is_not_a_fall() -> None:
    # the same 15 % fall: clean, it counts; under batch noise of 40 % on 10-iteration windows it
    # is within two standard errors, and the limit drops below the ratio
    clean = np.linspace(1.0, 0.85, 100)
    assert fit_warnings(clean.tolist()) == []
    noise = 1 + 0.4 * np.random.default_rng(7).standard_normal(100)
    ratio, se = loss_ratio(clean * noise)  # 0.84 ± 0.15
    assert se > 0.1 and loss_limit(se) <= ratio < LOSS_RATIO_LIMIT
    found = fit_warnings((clean * noise).tolist())
    assert [w.code for w in found] == ["loss_not_falling"] and found[0].limit == pytest.approx(loss_limit(se))


def test_short_or_empty_histories_are_not_judged() -> None:
    assert fit_warnings([]) == []
    assert fit_warnings([1.0] * (LOSS_MIN_ITERS - 1)) == []
    assert loss_ratio([1.0] * LOSS_MIN_ITERS) == pytest.approx((1.0, 0.0))


def test_warning_line_and_json_round_trip() -> None:
    w = ResultWarning(code="box_filling", message="fills", measure=0.5123, limit=0.4)
    assert w.line("reed") == "reed: fills (0.512 vs limit 0.4)"
    assert ResultWarning.model_validate_json(w.model_dump_json()) == w
