"""The plane of best focus of a single-height (or elevation-poor) survey, for its report."""

from __future__ import annotations

from typing import Any

import numpy as np

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import Survey
from shsas_core.outputs.report import ReportFigures


def add_focus(summary: dict[str, Any], figures: ReportFigures, survey: Survey, signals: np.ndarray) -> None:
    """A single-height (or elevation-poor) survey's report shows its plane of best focus.

    :func:`~shsas_core.imaging.planar.find_focus` searches every height the geometry allows, not only
    the scene box. Its record goes into the summary's elevation entry (``focus``); a focus
    also gives ``focus_height_m``, the backprojection of that plane (``figures.plane``) and
    the outline measured in it with the range resolution beside it; none found gives a
    warning in the summary's ``warnings`` instead.

    Args:
        summary: :func:`~shsas_core.formats.hdf5.summarize` of the survey, updated in place.
        figures: the report's figures, updated in place.
        survey: the training pings. signals: (N, T) their deconvolved signals.
    """
    elev = summary.get("elevation") or {}
    if elev.get("kind", "3d") == "3d":
        return
    from shsas_core.imaging.planar import find_focus, outline, plane_image

    focus = find_focus(survey, signals)
    elev["focus"] = focus.summary()
    figures.focus = focus
    if not focus.found:
        summary.setdefault("warnings", []).append(focus.reason)
        return
    elev["focus_height_m"] = focus.z
    plane = plane_image(survey, signals, focus.z)
    figures.plane = plane
    try:
        elev["outline"] = {**outline(plane.values, plane.grid).model_dump(),
                           "range_resolution_m": focus.range_resolution_m}
    except ShsasError:  # nothing outlined (an empty plane): the report shows the image alone
        pass
