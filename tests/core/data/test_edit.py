"""Survey edits (shsas_core/data/edit.py): each against what it should do, by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shsas_core.common.errors import ShsasError
from shsas_core.data import edit
from shsas_core.data.survey import SceneBox
from tests.helpers.focus_scenes import levels_scene


@pytest.fixture(scope="module")
def levels():
    return levels_scene(angles=12, levels=3)  # 36 pings, 12 per level


def test_parse_sound_speed():
    assert edit.parse_sound_speed("343.2", 340.0) == 343.2
    assert edit.parse_sound_speed("+2%", 340.0) == pytest.approx(346.8)
    assert edit.parse_sound_speed("-0.5%", 340.0) == pytest.approx(338.3)
    assert edit.parse_sound_speed("+0.7", 340.0) == pytest.approx(340.7)
    assert edit.parse_sound_speed("-0.7", 340.0) == pytest.approx(339.3)
    for bad in ("fast", "2%", "+%", "", "1e3"):
        with pytest.raises(ShsasError, match="--sound-speed"):
            edit.parse_sound_speed(bad, 340.0)


def test_sound_speed_is_validated_and_logged(levels):
    out = edit.set_sound_speed(levels, 350.0)
    assert out.meta.sound_speed == 350.0 and "sound_speed" in out.meta.attrs["edits"]
    assert np.array_equal(out.samples, levels.samples) and np.array_equal(out.t0, levels.t0)
    with pytest.raises(ShsasError, match="sound_speed"):
        edit.set_sound_speed(levels, 50.0)


def test_range_offset_moves_t0_and_drops_samples_below_zero(levels):
    c = levels.meta.sound_speed
    out = edit.shift_range(levels, 0.01)
    assert np.allclose(out.t0, levels.t0 - 0.02 / c) and out.shape == levels.shape
    # an offset past the record's lead: the samples before transmit are dropped
    from tests.conftest import make_survey

    short = make_survey(t=1200)
    fs = short.meta.fs
    short = dataclasses.replace(short, t0=np.full(short.num_pings, 2.5 / fs))
    c = short.meta.sound_speed
    dr = 0.5 * c * 4.0 / fs  # t0 would be -1.5 samples
    out = edit.shift_range(short, dr)
    assert out.num_samples == 1200 - 2 and np.array_equal(out.samples, short.samples[:, 2:])
    # the samples kept are at the times they were, less the removed delay
    assert np.allclose(out.t0, 2.5 / fs - 2 * dr / c + 2 / fs) and out.t0.min() >= 0
    with pytest.raises(ShsasError, match="before transmit"):
        edit.shift_range(short, 0.5 * c * 2000 / fs)


def test_level_heights_move_each_level(levels):
    from shsas_core.data.geometry import height_levels

    lv = height_levels(levels.tx)
    new = [float(h) + d for h, d in zip(lv.heights, (0.0, 0.01, -0.02), strict=True)]
    out = edit.set_level_heights(levels, new)
    assert np.allclose(height_levels(out.tx).heights, new)
    dz = out.tx[:, 2] - levels.tx[:, 2]
    assert np.allclose(out.rx[:, 2] - levels.rx[:, 2], dz)
    assert np.allclose(out.tx[:, :2], levels.tx[:, :2])
    with pytest.raises(ShsasError, match="3 height levels"):
        edit.set_level_heights(levels, [0.1, 0.2])


def test_subsets_and_their_metadata(levels):
    from shsas_core.data.geometry import height_levels

    s = dataclasses.replace(levels, meta=levels.meta.model_copy(
        update={"attrs": {**levels.meta.attrs, "height_levels": 3, "pings_per_level": 12}}))
    two = edit.keep_levels(s, [0, 2])
    lv = height_levels(two.tx)
    assert lv.count == 2 and two.num_pings == 24
    assert two.meta.attrs["height_levels"] == 2 and two.meta.attrs["pings_per_level"] == 12
    third = edit.every_step(s, 3)
    assert third.num_pings == 12 and third.meta.attrs["pings_per_level"] == 4
    assert np.array_equal(third.tx, s.tx[np.arange(36) % 3 == 0])  # 12 per level: every 3rd in each
    some = edit.keep_count(s, 10)
    counts = np.bincount(height_levels(some.tx).index)
    assert some.num_pings == 10 and "pings_per_level" not in some.meta.attrs  # 4/3/3: unequal
    assert some.meta.attrs["height_levels"] == len(counts)
    for bad in (lambda: edit.keep_levels(s, [3]), lambda: edit.every_step(s, 0), lambda: edit.keep_count(s, 37)):
        with pytest.raises(ShsasError):
            bad()


def test_scene_box_is_checked_against_the_record(levels):
    box = SceneBox(min=(-0.05, -0.05, 0.0), max=(0.05, 0.05, 0.05))
    assert edit.set_scene_box(levels, box).meta.scene_box == box
    with pytest.raises(ShsasError, match="scene_box"):
        edit.set_scene_box(levels, SceneBox(min=(50, 50, 50), max=(51, 51, 51)))
