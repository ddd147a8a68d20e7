"""Operator corrections of a survey: sound speed, range offset, scene box, level heights, and
subsets of pings by height level, turntable step or count (what ``shsas edit`` does).

Each edit returns a new :class:`~shsas_core.data.survey.Survey`; the samples are never resampled.
Subsets go through :meth:`Survey.subset`, which keeps the metadata that counts pings true.
Every edit is appended to ``meta.attrs["edits"]`` (one ``; ``-separated line) so a file says
what was done to it.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np

from shsas_core.common.errors import ShsasError
from shsas_core.data.geometry import height_levels
from shsas_core.data.survey import SceneBox, Survey, parse_meta

_SPEED = re.compile(r"^\s*([+-]?)(\d+(?:\.\d*)?|\.\d+)(%?)\s*$")


def _logged(survey: Survey, line: str, **update: object) -> Survey:
    """``survey`` with ``meta`` updated and ``line`` appended to ``meta.attrs["edits"]``."""
    attrs = dict(update.pop("attrs", survey.meta.attrs))  # type: ignore[call-overload]
    old = str(attrs.get("edits", ""))
    attrs["edits"] = f"{old}; {line}" if old else line
    return dataclasses.replace(survey, meta=survey.meta.model_copy(update={**update, "attrs": attrs}))


def parse_sound_speed(text: str, current: float) -> float:
    """``"343.2"`` (m/s), ``"+2%"`` / ``"-0.5%"`` (relative) or ``"+0.7"`` / ``"-0.7"`` (m/s added)."""
    m = _SPEED.match(text)
    if m is None:
        raise ShsasError(f"--sound-speed {text!r}: give m/s (343.2), a change in m/s (+0.7, -0.7) or in "
                         "percent (+2%, -0.5%)")
    sign, number, percent = m.groups()
    value = float(number)
    if not sign:
        if percent:
            raise ShsasError(f"--sound-speed {text!r}: a percentage needs a sign (+2% or -2%)")
        return value
    delta = value * (1 if sign == "+" else -1)
    return current * (1 + delta / 100) if percent else current + delta


def set_sound_speed(survey: Survey, speed: float) -> Survey:
    """The survey with ``meta.sound_speed = speed`` (m/s; validated like any meta field)."""
    old = survey.meta.sound_speed
    parse_meta({**survey.meta.model_dump(), "sound_speed": speed})  # raises, naming the bounds
    return _logged(survey, f"sound_speed {old!r} -> {speed!r} m/s", sound_speed=speed)


def shift_range(survey: Survey, offset_m: float) -> Survey:
    """Remove a one-way range offset ``offset_m`` (m): echoes arrived ``2 dr / c`` later than
    ``t0`` said, so ``t0`` moves earlier by that time (the sign of autofocus's
    ``range_offset``). A ``t0`` that would fall below zero drops the leading samples instead."""
    if not math.isfinite(offset_m):
        raise ShsasError(f"--range-offset: {offset_m} is not a finite number of metres")
    fs, (n, t) = survey.meta.fs, survey.shape
    t0 = survey.t0 - 2 * offset_m / survey.meta.sound_speed
    drop = math.ceil(max(0.0, -float(t0.min())) * fs - 1e-9)
    if drop >= t:
        raise ShsasError(f"--range-offset: {offset_m:g} m moves the whole record before transmit")
    samples, extras = survey.samples, dict(survey.extras)
    if drop:
        t0 = t0 + drop / fs
        samples = None if samples is None else samples[:, drop:]
        extras = {k: (v[:, drop:] if v.shape[:2] == (n, t) else v) for k, v in extras.items()}
    out = dataclasses.replace(survey, t0=t0, samples=samples, extras=extras, shape=(n, t - drop))
    return _logged(out, f"range_offset {offset_m!r} m removed" + (f" ({drop} leading samples dropped)" if drop else ""))


def set_scene_box(survey: Survey, box: SceneBox) -> Survey:
    """The survey with a new scene box (checked against the record like any survey's)."""
    out = _logged(survey, f"scene_box {list(box.min)}..{list(box.max)} m", scene_box=box)
    out.validate()
    return out


def set_level_heights(survey: Survey, heights: list[float]) -> Survey:
    """Move each height level's sensors so its mean TX height is ``heights[k]`` (m, one per
    level, lowest level first); RX moves with its TX."""
    levels = height_levels(survey.tx)
    if len(heights) != levels.count:
        raise ShsasError(f"--level-z: {len(heights)} heights for {levels.count} height levels (give one per "
                         f"level, lowest first; the levels are at {np.round(levels.heights, 4).tolist()} m)")
    if not np.all(np.isfinite(heights)) or np.any(np.diff(heights) <= 0):
        raise ShsasError("--level-z: give finite heights in ascending order, one per level")
    dz = (np.asarray(heights) - levels.heights)[levels.index]
    tx, rx = survey.tx.copy(), survey.rx.copy()
    tx[:, 2] += dz
    rx[:, 2] += dz
    out = dataclasses.replace(survey, tx=tx, rx=rx)
    return _logged(out, f"level heights {np.round(levels.heights, 6).tolist()} -> {list(heights)} m")


def keep_levels(survey: Survey, keep: list[int]) -> Survey:
    """Only the pings of height levels ``keep`` (indices, lowest level 0)."""
    levels = height_levels(survey.tx)
    bad = [k for k in keep if not 0 <= k < levels.count]
    if bad or not keep:
        raise ShsasError(f"--levels: {bad or 'nothing'} is not among the survey's levels 0..{levels.count - 1}")
    index = np.flatnonzero(np.isin(levels.index, keep))
    return _logged(survey.subset(index), f"kept levels {sorted(set(keep))}")


def every_step(survey: Survey, step: int) -> Survey:
    """Every ``step``-th ping of each height level, in recorded order (on a turntable scan: a
    turntable step ``step`` times as large), the first of each level kept."""
    if step < 1:
        raise ShsasError(f"--every: {step} must be a whole number of pings >= 1")
    levels = height_levels(survey.tx)
    rank = np.zeros(survey.num_pings, dtype=np.int64)
    for k in range(levels.count):
        members = np.flatnonzero(levels.index == k)
        rank[members] = np.arange(members.size)
    return _logged(survey.subset(np.flatnonzero(rank % step == 0)), f"kept every {step}th ping of each level")


def keep_count(survey: Survey, count: int) -> Survey:
    """``count`` pings evenly spaced over the survey, first and last kept."""
    if not 1 <= count <= survey.num_pings:
        raise ShsasError(f"--count: {count} is not between 1 and the survey's {survey.num_pings} pings")
    index = np.unique(np.linspace(0, survey.num_pings - 1, count).round().astype(np.int64))
    return _logged(survey.subset(index), f"kept {count} evenly spaced pings")
