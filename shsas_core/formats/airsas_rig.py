"""The AirSAS rig: what its three formats (raw CSV, processed pickle, deconvolved pings) share.

The turntable scene box is :class:`~shsas_core.data.survey.SceneBox`'s default; the sound
speed in air follows the acquisition software: ``c = 331.4 + 0.6·T`` (T in °C, m/s).
"""

from __future__ import annotations

from typing import Any

from shsas_core.data.survey import PulseParams, SceneBox, SurveyMeta, parse_meta


def sound_speed_air(temperature_c: float) -> float:
    """Sound speed in air, m/s, at ``temperature_c`` °C (the AirSAS software's rule)."""
    return 331.4 + 0.6 * temperature_c


def airsas_meta(fs: float, c: float, pparams: PulseParams, scene_box: SceneBox | None,
                attrs: dict[str, Any], **kw: Any) -> SurveyMeta:
    """The :class:`SurveyMeta` of an AirSAS survey: ``fs`` Hz, ``c`` m/s, the turntable box
    unless ``scene_box`` is given; ``kw`` are further meta fields (they may override ``platform``)."""
    data = {"fs": fs, "sound_speed": c, "pulse": pparams.model_dump(), "platform": "airsas",
            "scene_box": (scene_box or SceneBox()).model_dump(), "attrs": attrs, **kw}
    return parse_meta(data)
