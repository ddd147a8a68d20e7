"""Elevation-poor surveys: tell them apart, find the plane that holds the energy, image it.

A circular scan at one sensor height (AirSAS's ``cutout_20k``) has a synthetic aperture in
azimuth only. Its 3-D backprojection is a cone-shaped smear through the object, so a
maximum-intensity projection over z blurs what the z = const slices show sharply. For such a
survey the product images the plane of best focus instead:

* :func:`height_levels` groups the pings by sensor height;
* :func:`elevation_info` says whether the survey resolves elevation (``kind``: ``3d``,
  ``single-height`` or ``elevation-poor``) from the levels and the elevation aperture alone, so
  ``shsas info`` can tell without reading samples;
* :func:`focus_height` finds the height of the sharpest horizontal plane (image entropy of fast
  low-resolution backprojections, coarse grid then bounded Brent search);
  :func:`volume_focus_height` does the same on a finished volume, slice by slice;
* :func:`plane_image` backprojects one horizontal plane at full resolution;
* :func:`outline` measures an object's extent and edge width in a plane image.

On a single-height scan the plane height is not separable from a range offset or a sound-speed
error: a height error ``dz`` changes every two-way path by about ``2 dz sin(depression)``, the
same at every azimuth, which is what a range offset does (docs/usage.md, "shsas autofocus").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .errors import ShsasError
from .sharpness import Sharpness, focus_cost
from .survey import SceneBox, Survey
from .volume import Grid, Volume

#: Pings whose TX heights differ by no more than this share a height level, m.
LEVEL_TOLERANCE_M = 1e-3
#: A survey whose elevation aperture resolves less than this fraction of the scene box's
#: height is elevation-poor: its images are effectively 2-D.
ELEVATION_POOR_FRACTION = 0.5
#: Pixels along the longest axis of the low-resolution images of the focus-height search.
SEARCH_PIXELS = 48
#: Gaussian smoothing (pixels) of the magnitude before :func:`outline` finds the object's region.
OUTLINE_SMOOTH_PX = 2.0


ElevationKind = Literal["3d", "single-height", "elevation-poor"]


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


def plane_grid(box: SceneBox, z: float, longest: int) -> Grid:
    """A one-voxel-thick grid over the box's x-y extent, centred on height ``z``."""
    size = box.size[:2]
    step = float(size.max()) / longest
    nx, ny = (max(1, round(float(s) / step)) for s in size)
    half = 0.5 * step
    return Grid((box.min[0], box.min[1], z - half), (box.max[0], box.max[1], z + half), (nx, ny, 1))


def plane_image(survey: Survey, signals: np.ndarray, z: float, longest: int = 200,
                box: SceneBox | None = None, device: str = "cpu") -> Volume:
    """Backprojection of the horizontal plane at height ``z`` (a (nx, ny, 1) volume)."""
    from .backprojection import backproject_survey

    grid = plane_grid(box or survey.meta.scene_box, z, longest)
    return backproject_survey(survey, grid, signals, device=device)


def focus_height(survey: Survey, signals: np.ndarray, *, measure: Sharpness = "entropy",
                 z_range: tuple[float, float] | None = None, tolerance: float = 5e-4,
                 pixels: int = SEARCH_PIXELS, pings: np.ndarray | None = None) -> float:
    """Height of the sharpest horizontal plane, m.

    Coarse: the focus cost of low-resolution plane images every range resolution over
    ``z_range`` (default: the scene box's z extent widened by a quarter of its height on each
    side: an object on the box's floor may focus just below it); fine: bounded Brent search
    (``scipy.optimize.minimize_scalar``) in the bracket around the best coarse plane.
    """
    from scipy.optimize import minimize_scalar

    from .quicklook import Geometry, QuickImager

    box = survey.meta.scene_box
    pad = 0.25 * float(box.size[2])
    lo, hi = z_range or (box.min[2] - pad, box.max[2] + pad)
    if not hi > lo:
        raise ShsasError(f"focus height: empty z range [{lo}, {hi}]")
    # one image size for both passes: the cost's minimum over z is flat (on the AirSAS cut-out
    # within 0.001 nats over 15 mm), and a coarser image moved it by 13 mm
    imager = QuickImager(survey, signals, pings)
    idx = imager.pings
    geo = Geometry(survey.tx[idx], survey.rx[idx], survey.t0[idx], survey.meta.sound_speed)
    xy = plane_grid(box, 0.0, pixels).points()[:, :2]

    def cost(z: float) -> float:
        pts = np.column_stack([xy, np.full(len(xy), z)])
        return focus_cost(imager.image(geo, pts), measure)

    step = survey.meta.sound_speed / (2 * survey.meta.pulse.bandwidth)
    zs = np.linspace(lo, hi, max(3, math.ceil((hi - lo) / step) + 1))
    costs = [cost(float(z)) for z in zs]
    k = int(np.argmin(costs))
    a, b = zs[max(k - 1, 0)], zs[min(k + 1, len(zs) - 1)]
    res = minimize_scalar(cost, bounds=(float(a), float(b)), method="bounded", options={"xatol": tolerance})
    return float(res.x)


def volume_focus_height(volume: Volume, measure: Sharpness = "entropy") -> float:
    """Centre height of the volume's sharpest z slice, m (no new imaging)."""
    vals = np.asarray(volume.values)
    costs = [focus_cost(vals[:, :, k], measure) for k in range(vals.shape[2])]
    return float(volume.grid.axes()[2][int(np.argmin(costs))])


class Outline(BaseModel):
    """An edge-lit object's size in a plane image (see :func:`outline`); axes x then y."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    centre_m: tuple[float, float]
    extent_m: tuple[float, float] = Field(
        description="between the edges' outer half-maximum points (where the rim's brightness has "
        "fallen halfway to the background outside it), m")
    ridge_extent_m: tuple[float, float] = Field(description="between the edge ridges' crests, m")
    edge_fall_m: tuple[float, float, float, float] = Field(
        description="distance over which the -x, +x, -y, +y edges fall outward from 90 % to 10 % of "
        "their height above the background, m")


def outline(image: np.ndarray, grid: Grid, threshold: float = 0.25) -> Outline:
    """Measure an edge-lit object (a flat plate seen at grazing angles shows its rim) in a plane.

    The object is the largest connected region where the magnitude, smoothed over
    :data:`OUTLINE_SMOOTH_PX` pixels, exceeds ``threshold`` of its peak (holes filled). Along x,
    the magnitude is averaged over the middle half of the region's y span; the two edges are
    the crests of that profile left and right of the region's centre, and each edge's outer
    flank is followed outward to the background (the profile's lowest value on that side):
    the half-height point gives the extent, the 90 % and 10 % points the edge's fall. Likewise
    along y. Crossings are interpolated linearly between pixels.
    """
    from scipy import ndimage

    mag = np.abs(np.asarray(image))
    if mag.ndim == 3:
        mag = mag[:, :, 0]
    peak = float(mag.max())
    if peak <= 0:
        raise ShsasError("outline: the image is all zeros")
    mag = mag / peak
    # the region is found on a smoothed image: a speckled rim must not split into pieces
    smooth = ndimage.gaussian_filter(mag, OUTLINE_SMOOTH_PX)
    mask = ndimage.binary_fill_holes(ndimage.binary_closing(smooth > threshold * smooth.max(), iterations=2))
    lab, count = ndimage.label(mask)
    if count == 0:
        raise ShsasError("outline: nothing above the threshold")
    sizes = ndimage.sum(mask, lab, range(1, count + 1))
    region = lab == int(np.argmax(sizes)) + 1
    xs, ys, _ = grid.axes()
    d = grid.spacing[:2]
    ii, jj = np.nonzero(region)
    centre, extent, ridges, falls = [], [], [], []
    for axis, (idx, other, coords) in enumerate(((ii, jj, xs), (jj, ii, ys))):
        o_lo, o_hi = np.percentile(other, [25, 75]).round().astype(int)
        band = mag[:, o_lo:o_hi + 1].mean(1) if axis == 0 else mag[o_lo:o_hi + 1, :].mean(0)
        c = round(idx.mean())
        lo_i, hi_i = int(idx.min()), int(idx.max())
        crest = (lo_i + int(np.argmax(band[lo_i:c + 1])), c + int(np.argmax(band[c:hi_i + 1])))
        half, fall = [], []
        for k, step in zip(crest, (-1, 1), strict=True):
            floor = float(band[: k + 1].min() if step < 0 else band[k:].min())
            top = float(band[k]) - floor
            half.append(_crossing(band, k, step, floor + 0.5 * top))
            fall.append(abs(_crossing(band, k, step, floor + 0.1 * top)
                            - _crossing(band, k, step, floor + 0.9 * top)) * d[axis])
        extent.append((half[1] - half[0]) * d[axis])
        ridges.append((crest[1] - crest[0]) * d[axis])
        centre.append(coords[0] + 0.5 * (half[0] + half[1]) * d[axis])
        falls += fall
    return Outline(centre_m=(centre[0], centre[1]), extent_m=(extent[0], extent[1]),
                   ridge_extent_m=(ridges[0], ridges[1]), edge_fall_m=tuple(falls))  # type: ignore[arg-type]


def _crossing(p: np.ndarray, k: int, step: int, level: float) -> float:
    """Fractional index where ``p`` first drops to ``level`` going from ``k`` in direction ``step``."""
    i = k
    while 0 <= i + step < len(p) and p[i + step] > level:
        i += step
    j = i + step
    if not 0 <= j < len(p):
        return float(i)
    return i + step * (p[i] - level) / (p[i] - p[j]) if p[i] != p[j] else float(j)
