"""Elevation-poor surveys: tell them apart, find the plane that holds the energy, image it.

A circular scan at one sensor height (AirSAS's ``cutout_20k``) has a synthetic aperture in
azimuth only. Its 3-D backprojection is a cone-shaped smear through the object, so a
maximum-intensity projection over z blurs what the z = const slices show sharply. For such a
survey the product images the plane of best focus instead:

* :mod:`shsas_core.data.geometry` says whether a survey resolves elevation at all;
* :func:`find_focus` finds the height of the sharpest horizontal plane (image entropy of fast
  low-resolution backprojections, coarse grid then bounded Brent search) anywhere between the
  deepest plane the recording reaches and the sensors, and says when there is none;
  :func:`volume_focus_height` finds the sharpest slice of a finished volume;
* :func:`plane_image` backprojects one horizontal plane at full resolution;
* :func:`outline` measures an object's extent and edge width in a plane image.

On a single-height scan the plane height is not separable from a range offset or a sound-speed
error: a height error ``dz`` changes every two-way path by about ``2 dz sin(depression)``, the
same at every azimuth, which is what a range offset does (docs/usage.md, "shsas autofocus").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import SceneBox, Survey
from shsas_core.data.volume import Grid, Volume
from shsas_core.imaging.sharpness import Sharpness, focus_cost

#: Pixels along the longest axis of the low-resolution images of the focus-height search.
SEARCH_PIXELS = 48
#: The focus search's measure: entropy found the cut-out's plane on the real AirSAS scan
#: (-10.3 mm against about -11.5) and the simulated narrowband scan's; contrast landed at
#: -35.4 mm on the real scan
#: (docs/usage.md, "Single-height scans").
FOCUS_MEASURE: Sharpness = "entropy"
#: The focus search images at most this many pings (evenly spread) ...
FOCUS_MAX_PINGS = 360
#: ... on at most this many coarse planes.
FOCUS_MAX_PLANES = 240
#: Whether the focus search's images run through the ``torch.compile``-d kernel. A search makes at
#: most a few hundred small images (FOCUS_MAX_PLANES coarse planes, a Brent search, each of
#: SEARCH_PIXELS² pixels over at most FOCUS_MAX_PINGS pings): compiling them costs more than it
#: saves unless the process compiles anyway (autofocus does), so a report's search runs eagerly
#: (benchmarks/bench_focus.py --backends eager,compiled prints both in fresh processes).
FOCUS_COMPILED = False
#: A focus must lie this far (nats of entropy, or of log contrast) below both ends of the
#: search: near the sensors the measure flattens, and its noise there is a few thousandths.
FOCUS_MIN_DEPTH = 0.02
#: Gaussian smoothing (pixels) of the magnitude before :func:`outline` finds the object's region.
OUTLINE_SMOOTH_PX = 2.0


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
    from shsas_core.imaging.backprojection import backproject_survey

    grid = plane_grid(box or survey.meta.scene_box, z, longest)
    return backproject_survey(survey, grid, signals, device=device)


@dataclasses.dataclass(frozen=True)
class FocusResult:
    """The outcome of :func:`find_focus`.

    Attributes:
        z: height of the sharpest plane searched, m (the search edge when not ``found``).
        found: True when the sharpest plane is an interior minimum of the measure, deeper than
            :data:`FOCUS_MIN_DEPTH` below both ends of the search.
        reason: why no focus was found (None when found).
        heights: (K,) heights of the coarse search planes, m, ascending.
        costs: (K,) the measure's cost at each (lower is sharper; :func:`~.sharpness.focus_cost`).
        measure: the sharpness measure.
        z_range: the heights searched, m.
        range_resolution_m: ``c / 2B`` of the survey, m.
    """

    z: float
    found: bool
    reason: str | None
    heights: np.ndarray
    costs: np.ndarray
    measure: Sharpness
    z_range: tuple[float, float]
    range_resolution_m: float

    def summary(self) -> dict[str, object]:
        """A JSON-able record (report.json's ``survey.elevation.focus``)."""
        return {"found": self.found, "z_m": self.z, "reason": self.reason, "measure": self.measure,
                "search_range_m": list(self.z_range), "heights_m": self.heights.round(5).tolist(),
                "costs": self.costs.round(5).tolist(), "range_resolution_m": self.range_resolution_m}


def search_range(survey: Survey) -> tuple[float, float]:
    """Heights the geometry allows a scene plane at, m: up to the lowest sensor, down to as far
    below the scene box's floor as that sensor stands above it (and no deeper than the
    recording reaches below the box's centre: every ping's record must end past the two-way
    path). Not the scene box: an object on a turntable may focus below the box's floor, and a
    box set too high must not hide it; a scene further below the floor than the sensors are
    above it would mean a box wrong by more than its whole height below the sensors."""
    box = survey.meta.scene_box
    centre = box.center
    top = float(min(survey.tx[:, 2].min(), survey.rx[:, 2].min()))
    end = survey.meta.sound_speed * (survey.t0 + (survey.num_samples - 1) / survey.meta.fs)

    def path(z: np.ndarray) -> np.ndarray:
        p = np.column_stack([np.full_like(z, centre[0]), np.full_like(z, centre[1]), z])
        return np.linalg.norm(survey.tx - p, axis=1) + np.linalg.norm(survey.rx - p, axis=1)

    # the two-way path grows monotonically going down from the sensors: bisection per ping
    hi = np.full(survey.num_pings, top)
    lo = hi - float(end.max())
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        inside = path(mid) <= end
        hi = np.where(inside, mid, hi)
        lo = np.where(inside, lo, mid)
    floor = float(box.min[2])
    bottom = min(max(float(hi.max()), floor - max(top - floor, 0.0)), floor)
    if not top > bottom:
        raise ShsasError(f"focus search: no height range between the record's reach ({bottom:.3f} m) and the "
                         f"lowest sensor ({top:.3f} m) (fix: check the sensor heights, t0 and the scene box)")
    return bottom, top


def _without_ping_mean(survey: Survey, signals: np.ndarray) -> np.ndarray:
    """The signals less their mean over pings at each delay.

    A return at the same delay in every ping says nothing about where along the aperture it
    came from. On a turntable scan (the sensors stand still, the scene turns) the room's
    echoes are such returns: they focus to one sharp spot on the rotation axis at whatever
    height their range puts it, sharper than any object (on the AirSAS cut-out scan, below
    the turntable at -0.5 m and -1.0 m).

    Pings whose first samples lie a whole number of samples apart are aligned on one time axis
    first; other surveys are left as they are.
    """
    shift = (survey.t0 - survey.t0.min()) * survey.meta.fs
    offset = np.round(shift).astype(np.int64)
    if np.any(np.abs(shift - offset) > 1e-3):
        return signals
    n, t = signals.shape
    cols = offset[:, None] + np.arange(t)[None, :]  # each sample's place on the common axis
    total = np.zeros(int(offset.max()) + t, dtype=signals.dtype)
    count = np.zeros(total.size)
    np.add.at(total, cols, signals)
    np.add.at(count, cols, 1.0)
    # delays that few pings recorded have no mean worth the name: left as they are
    mean = np.where(count >= 0.5 * n, total / np.maximum(count, 1.0), 0.0)
    return signals - mean[cols]


def find_focus(survey: Survey, signals: np.ndarray, *, measure: Sharpness = FOCUS_MEASURE,
               z_range: tuple[float, float] | None = None, tolerance: float = 5e-4,
               pixels: int = SEARCH_PIXELS, pings: np.ndarray | None = None,
               compiled: bool = FOCUS_COMPILED) -> FocusResult:
    """The height of the sharpest horizontal plane over the scene box's x-y extent.

    Coarse: the focus cost of low-resolution plane images every range resolution (at most
    :data:`FOCUS_MAX_PLANES` planes) over ``z_range`` (default :func:`search_range`); fine:
    bounded Brent search (``scipy.optimize.minimize_scalar``) between the best coarse plane's
    neighbours. A best plane at either end of the search, or less than
    :data:`FOCUS_MIN_DEPTH` below both ends, is not a focus: ``found`` is False and
    ``reason`` says why.

    Args:
        survey: the survey (geometry; its samples are not read).
        signals: (N, T) complex deconvolved signals on the survey's time axis.
        measure: the sharpness measure (:mod:`shsas_core.imaging.sharpness`).
        z_range: (low, high) heights to search, m.
        tolerance: the fine search's height tolerance, m.
        pixels: image pixels along the box's longest horizontal side.
        pings: which pings to image (default: at most :data:`FOCUS_MAX_PINGS`, evenly spread).
        compiled: image through the compiled kernel (:data:`FOCUS_COMPILED`); the result is the
            same to float rounding.
    """
    from scipy.optimize import minimize_scalar

    from shsas_core.imaging.quicklook import Geometry, QuickImager

    box = survey.meta.scene_box
    lo, hi = z_range or search_range(survey)
    if not hi > lo:
        raise ShsasError(f"focus search: empty z range [{lo}, {hi}]")
    if pings is None:
        pings = np.unique(np.linspace(0, survey.num_pings - 1, min(FOCUS_MAX_PINGS, survey.num_pings))
                          .round().astype(np.int64))
    # one image size for both passes: the cost's minimum over z is flat (on the AirSAS cut-out
    # within 0.001 nats over 15 mm), and a coarser image moved it by 13 mm
    imager = QuickImager(survey, _without_ping_mean(survey, np.asarray(signals)), pings, compiled=compiled)
    idx = imager.pings
    geo = Geometry(survey.tx[idx], survey.rx[idx], survey.t0[idx], survey.meta.sound_speed)
    xy = plane_grid(box, 0.0, pixels).points()[:, :2]

    def cost(z: float) -> float:
        pts = np.column_stack([xy, np.full(len(xy), z)])
        return focus_cost(imager.image(geo, pts), measure)

    res_m = survey.meta.range_resolution
    step = max(res_m, (hi - lo) / (FOCUS_MAX_PLANES - 1))
    zs = np.linspace(lo, hi, max(3, math.ceil((hi - lo) / step) + 1))
    costs = np.array([cost(float(z)) for z in zs])
    k = int(np.argmin(costs))
    common = {"heights": zs, "costs": costs, "measure": measure, "z_range": (float(lo), float(hi)),
              "range_resolution_m": res_m}
    if k in (0, len(zs) - 1):
        edge = "lowest" if k == 0 else "highest"
        return FocusResult(z=float(zs[k]), found=False, **common,  # type: ignore[arg-type]
                           reason=f"no plane of focus: the sharpest plane is the search's {edge}, "
                           f"z = {zs[k]:.3f} m ({measure} falls all the way to the edge of "
                           f"{lo:.3f}..{hi:.3f} m); the survey's band ({res_m * 1e3:.0f} mm range "
                           "resolution) or its geometry does not fix the height of the scene plane")
    fine = minimize_scalar(cost, bounds=(float(zs[k - 1]), float(zs[k + 1])), method="bounded",
                           options={"xatol": tolerance})
    z, c_min = float(fine.x), min(float(fine.fun), float(costs[k]))
    z = z if float(fine.fun) <= costs[k] else float(zs[k])
    depth = float(min(costs[0], costs[-1])) - c_min
    if depth < FOCUS_MIN_DEPTH:
        return FocusResult(z=z, found=False, **common,  # type: ignore[arg-type]
                           reason=f"no plane of focus: the sharpest plane, z = {z:.3f} m, is only "
                           f"{depth:.3f} below the sharper end of the search ({lo:.3f}..{hi:.3f} m), "
                           f"under {FOCUS_MIN_DEPTH}: the measure is flat over height")
    return FocusResult(z=z, found=True, reason=None, **common)  # type: ignore[arg-type]


def focus_height(survey: Survey, signals: np.ndarray, **kwargs: Any) -> float:
    """:func:`find_focus`'s height alone, m (whether or not it is a focus)."""
    return find_focus(survey, signals, **kwargs).z


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
