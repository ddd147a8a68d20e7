"""A survey's sensor geometry as imaging sees it: range bounds, height levels and elevation coverage.

* :func:`two_way_range_bounds` bounds each ping's two-way path to the scene box;
* :func:`height_levels` groups the pings by sensor height;
* :func:`elevation_info` says whether the survey resolves elevation (``kind``: ``3d``,
  ``single-height`` or ``elevation-poor``) from the levels and the elevation aperture alone, so
  ``shsas info`` and the survey file's summary can tell without reading samples.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

if TYPE_CHECKING:
    from shsas_core.data.survey import SceneBox, Survey

#: Pings whose TX heights differ by no more than this share a height level, m.
LEVEL_TOLERANCE_M = 1e-3
#: A survey whose elevation aperture resolves less than this fraction of the scene box's
#: height is elevation-poor: its images are effectively 2-D.
ELEVATION_POOR_FRACTION = 0.5


ElevationKind = Literal["3d", "single-height", "elevation-poor"]


def two_way_range_bounds(tx: np.ndarray, rx: np.ndarray, box: SceneBox) -> tuple[np.ndarray, np.ndarray]:
    """Per-ping shortest and longest two-way path from TX to any point of ``box`` to RX, m.

    Args:
        tx, rx: (N, 3) sensor positions, m. box: the scene box.
    Returns:
        r_min, r_max: (N,) m. ``r_min`` uses the box point closest to each sensor (a lower bound),
        ``r_max`` the farthest corner (an upper bound), so every scene point lies between them.
    """
    lo, hi = np.asarray(box.min, dtype=np.float64), np.asarray(box.max, dtype=np.float64)

    def near(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(p - np.clip(p, lo, hi), axis=1)

    def far(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.maximum(np.abs(p - lo), np.abs(p - hi)), axis=1)

    return near(tx) + near(rx), far(tx) + far(rx)


@dataclasses.dataclass(frozen=True)
class HeightLevels:
    """Pings grouped by TX height.

    Attributes:
        heights: (K,) mean TX height of each level, m, ascending.
        index: (N,) level of each ping.
    """

    heights: np.ndarray
    index: np.ndarray

    @property
    def count(self) -> int:
        return int(self.heights.size)


def height_levels(tx: np.ndarray, tolerance: float = LEVEL_TOLERANCE_M) -> HeightLevels:
    """Group pings into height levels: sorted TX heights split where consecutive ones differ by
    more than ``tolerance`` (a helical scan, every ping at its own height, gives N levels)."""
    z = np.asarray(tx, dtype=np.float64)[:, 2]
    order = np.argsort(z, kind="stable")
    zs = z[order]
    starts = np.concatenate([[0], np.flatnonzero(np.diff(zs) > tolerance) + 1])
    label_sorted = np.zeros(z.size, dtype=np.int64)
    label_sorted[starts[1:]] = 1
    label_sorted = np.cumsum(label_sorted)
    index = np.empty_like(label_sorted)
    index[order] = label_sorted
    heights = np.array([zs[label_sorted == k].mean() for k in range(len(starts))])
    return HeightLevels(heights=heights, index=index)


class ElevationInfo(BaseModel):
    """How well a survey resolves elevation (from its geometry alone)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: ElevationKind
    levels: int = Field(ge=1, description="distinct TX height levels")
    elevation_span_deg: float = Field(ge=0, description="spread of the sensors' elevation angles seen "
                                      "from the scene-box centre, degrees")
    vertical_resolution_m: float | None = Field(
        description="λ_c / (2 · span): the elevation aperture's vertical resolution; None for one level")
    message: str

    @property
    def planar(self) -> bool:
        """True when images should be read as 2-D (single-height or elevation-poor)."""
        return self.kind != "3d"


def elevation_info(survey: Survey) -> ElevationInfo:
    """Classify a survey's elevation coverage (see the module docstring)."""
    levels = height_levels(survey.tx)
    box = survey.meta.scene_box
    centre = box.center
    mid = 0.5 * (survey.tx + survey.rx) - centre
    elev = np.arctan2(mid[:, 2], np.hypot(mid[:, 0], mid[:, 1]))
    span = float(elev.max() - elev.min())
    lam = survey.meta.sound_speed / survey.meta.pulse.f_center
    height = float(box.size[2])
    if levels.count == 1:
        return ElevationInfo(
            kind="single-height", levels=1, elevation_span_deg=math.degrees(span), vertical_resolution_m=None,
            message=f"single-height survey: every ping is at TX height {levels.heights[0]:.4f} m, so there "
            "is no elevation aperture; images are 2-D: the report shows the plane of best focus and its "
            "height instead of projections of a 3-D volume")
    res = lam / (2 * span) if span > 0 else math.inf
    if res > ELEVATION_POOR_FRACTION * height:
        return ElevationInfo(
            kind="elevation-poor", levels=levels.count, elevation_span_deg=math.degrees(span),
            vertical_resolution_m=res if math.isfinite(res) else None,
            message=f"elevation-poor survey: {levels.count} height levels spanning "
            f"{math.degrees(span):.2f} deg resolve about {res:.3g} m vertically, coarser than half the "
            f"scene box's height ({height:.3g} m); images are read as 2-D (plane of best focus)")
    return ElevationInfo(kind="3d", levels=levels.count, elevation_span_deg=math.degrees(span),
                         vertical_resolution_m=res,
                         message=f"{levels.count} height levels spanning {math.degrees(span):.2f} deg: "
                         f"about {res:.3g} m vertical resolution")
