"""The survey variants: each changes what it names and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import PulseParams
from shsas_core.simulation.simulate import SimulationConfig
from shsas_core.simulation.variants import VARIANTS, variant_overrides

BOUNDS = np.array([[-0.1, -0.05, 0.0], [0.1, 0.08, 0.18]])


@pytest.mark.parametrize("name", sorted(set(VARIANTS) - {"snr_5db"}))
def test_each_variant_is_a_valid_simulation_config(name: str) -> None:
    cfg = SimulationConfig(**variant_overrides(name, BOUNDS))
    changed = {k for k in SimulationConfig.model_fields if getattr(cfg, k) != getattr(SimulationConfig(), k)}
    assert len(changed) == (0 if name == "reference" else 1)


def test_narrowband_keeps_the_centre_and_cuts_the_band_to_a_quarter() -> None:
    pulse = variant_overrides("narrowband", BOUNDS)["pulse"]
    default = PulseParams()
    assert pulse.f_center == pytest.approx(default.f_center)
    assert abs(pulse.f_stop - pulse.f_start) == pytest.approx(abs(default.f_stop - default.f_start) / 4)


def test_wideband_doubles_the_band_below_nyquist() -> None:
    pulse = variant_overrides("wideband", BOUNDS)["pulse"]
    default = PulseParams()
    assert abs(pulse.f_stop - pulse.f_start) == pytest.approx(2 * abs(default.f_stop - default.f_start))
    assert 2 * max(pulse.f_start, pulse.f_stop) < SimulationConfig().fs


def test_large_box_holds_the_object_with_room_above() -> None:
    box = variant_overrides("large_box", BOUNDS)["scene_box"]
    lo, hi = np.array(box.min), np.array(box.max)
    assert np.all(lo < BOUNDS[0]) and np.all(hi > BOUNDS[1])
    assert hi[2] - BOUNDS[1, 2] >= 0.15


def test_snr_variant_sets_the_snr_and_an_unknown_name_says_which_exist() -> None:
    assert variant_overrides("snr_5db", BOUNDS) == {"snr_db": 5.0}
    with pytest.raises(ShsasError, match="narrowband"):
        variant_overrides("ultrasound", BOUNDS)
