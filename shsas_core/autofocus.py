"""Autofocus: estimate survey parameters that are wrong or unknown from the image's sharpness.

A sonar image is sharpest when the geometry used to form it is the one the data were recorded
with. :func:`autofocus` searches the parameters below for the sharpest (lowest-entropy, or
highest-contrast: :mod:`shsas_core.sharpness`) fast low-resolution backprojection
(:mod:`shsas_core.quicklook`) and :func:`apply_correction` writes them into the survey:

* ``sound_speed``: ``c``, searched as a relative change of the survey's value;
* ``range_offset``: a one-way range offset ``dr``: echoes recorded ``2 dr / c`` late (an
  unremoved delay); corrected by moving ``t0`` earlier by that time;
* ``level_z``: a height offset per height level (:func:`shsas_core.planar.height_levels`), the
  lowest level held at zero: a common height shift of every sensor only moves the image. With
  ``level_z_knots = K`` the offsets are a piecewise-linear function of the level's height with K
  evenly spaced knots (K − 1 unknowns; K = 2 is a wrong height step): a scan of 150 levels is
  then searched with a handful of parameters instead of 149;
* ``radius``: the TX/RX circle radius about the z axis (circular scans): both sensors move
  radially by ``dρ``.

Search (coarse to fine): each parameter in turn over a grid (steps below the width of the cost's
minimum) on a coarse image of every second selected ping, then a joint bounded Powell
refinement (``scipy.optimize.minimize``) on the full search image.

Limits (docs/usage.md, "shsas autofocus"): on a single-height scan, sound speed, range offset and
the image plane's height trade off along one valley of the cost, so a planar survey is searched
in a fixed plane (``plane_z``) and needs either ``c`` or ``dr`` known to estimate the other;
``radius`` is nearly degenerate with ``range_offset`` for a scene near the axis.
"""

from __future__ import annotations

import json
import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .errors import ShsasError
from .planar import HeightLevels, elevation_info, focus_height, height_levels, plane_grid
from .progress import ProgressFn, no_progress
from .quicklook import Geometry, QuickImager
from .sharpness import Sharpness, focus_cost
from .survey import Survey
from .volume import Grid

Parameter = Literal["sound_speed", "range_offset", "level_z", "radius"]
PARAMETERS: tuple[str, ...] = ("sound_speed", "range_offset", "level_z", "radius")
#: Horizontal sensor radii about the z axis may vary this much (relative) for ``radius``.
CIRCULAR_TOLERANCE = 0.01


class AutofocusConfig(BaseModel):
    """What :func:`autofocus` searches and how."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    parameters: tuple[Parameter, ...] = Field(("sound_speed", "range_offset"), min_length=1)
    measure: Sharpness = "entropy"
    sound_speed_span: float = Field(0.04, gt=0, le=0.2, description="± relative search range of c")
    sound_speed_step: float = Field(0.0025, gt=0, description="coarse grid step of c, relative")
    range_offset_span_m: float = Field(0.02, gt=0, le=0.5, description="± search range of dr, m")
    range_offset_step_m: float = Field(0.001, gt=0, description="coarse grid step of dr, m")
    level_z_span_m: float = Field(0.02, gt=0, le=0.5, description="± search range of each level's dz, m")
    level_z_step_m: float = Field(0.002, gt=0, description="coarse grid step of dz, m")
    level_z_knots: int | None = Field(None, ge=2, le=64, description="level_z as a piecewise-linear "
                                      "function of height with this many knots (None: every level free)")
    radius_span_m: float = Field(0.02, gt=0, le=0.5, description="± search range of dρ, m")
    radius_step_m: float = Field(0.001, gt=0, description="coarse grid step of dρ, m")
    pixels: int = Field(48, ge=8, le=256, description="search image: pixels along the box's longest axis "
                        "(planar surveys); 3-D surveys use half as many voxels per axis")
    max_pings: int = Field(360, ge=8, description="evenly spaced pings used by the search")
    plane_z: float | None = Field(None, description="planar surveys: height of the imaged plane, m; None: "
                                  "the focus height under the input geometry")
    rounds: int = Field(1, ge=1, le=5, description="coordinate-wise coarse passes before the joint refinement")
    tolerance: float = Field(1e-3, gt=0, description="Powell xtol in units of each parameter's coarse step")


class Correction(BaseModel):
    """Estimated parameters (the survey's own values where not searched)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sound_speed: float = Field(gt=0, description="m/s")
    range_offset_m: float = Field(0.0, description="one-way range offset removed, m (t0 moved by -2 dr / c)")
    level_z_m: tuple[float, ...] = Field((), description="height offset added to each level's sensors, m")
    radius_offset_m: float = Field(0.0, description="radial move of TX and RX about the z axis, m")


class AutofocusResult(BaseModel):
    """What the search found."""

    model_config = ConfigDict(extra="forbid")

    correction: Correction
    original_sound_speed: float
    level_heights_m: list[float] = Field(description="TX height of each level before correction")
    parameters: list[str]
    measure: str
    plane_z: float | None = Field(description="height of the imaged plane (planar surveys), m")
    cost_before: float
    cost_after: float
    evaluations: int
    seconds: float
    notes: list[str] = Field(default_factory=list)


# ------------------------------------------------------------------------------------------
# the geometry a parameter vector stands for


def _check_circular(survey: Survey) -> None:
    for name, p in (("tx", survey.tx), ("rx", survey.rx)):
        r = np.hypot(p[:, 0], p[:, 1])
        if r.min() <= 0 or (r.max() - r.min()) > CIRCULAR_TOLERANCE * r.mean():
            raise ShsasError(f"autofocus: radius needs a circular scan about the z axis, but the {name} "
                             f"radii span {r.min():.4f}..{r.max():.4f} m (fix: leave radius out of --params)")


def corrected_geometry(tx: np.ndarray, rx: np.ndarray, t0: np.ndarray, levels: np.ndarray,
                       c0: float, corr: Correction) -> Geometry:
    """Sensor positions, first-sample times and sound speed after ``corr`` (arrays per ping)."""
    tx, rx = tx.copy(), rx.copy()
    if corr.level_z_m:
        dz = np.asarray(corr.level_z_m)[levels]
        tx[:, 2] += dz
        rx[:, 2] += dz
    if corr.radius_offset_m:
        for p in (tx, rx):
            r = np.hypot(p[:, 0], p[:, 1])
            p[:, :2] *= ((r + corr.radius_offset_m) / r)[:, None]
    # the offset is a time (2 dr / c0 with the survey's own c): it does not move when c does
    t0 = t0 - 2 * corr.range_offset_m / c0
    return Geometry(tx, rx, t0, corr.sound_speed)


def apply_correction(survey: Survey, corr: Correction, note: dict | None = None) -> Survey:
    """The survey with ``corr`` applied and the original values kept in ``meta.attrs``.

    A ``t0`` that would fall below zero (an offset larger than the record's lead) drops the
    leading samples instead: the same data, a later first sample. The original values go into
    ``meta.attrs["autofocus"]`` (JSON) and ``meta.attrs["autofocus_original_sound_speed"]``.
    """
    import dataclasses

    levels = height_levels(survey.tx)
    if corr.level_z_m and len(corr.level_z_m) != levels.count:
        raise ShsasError(f"autofocus: {len(corr.level_z_m)} level offsets for {levels.count} height levels")
    geo = corrected_geometry(survey.tx, survey.rx, survey.t0, levels.index, survey.meta.sound_speed, corr)
    t0 = geo.t0
    n, t = survey.shape
    drop = math.ceil(max(0.0, -float(t0.min())) * survey.meta.fs - 1e-9)
    if drop >= t:
        raise ShsasError(f"autofocus: range offset {corr.range_offset_m:.4g} m moves the whole record before "
                         "transmit")
    samples = survey.samples
    extras = dict(survey.extras)
    if drop:
        t0 = t0 + drop / survey.meta.fs
        samples = None if samples is None else samples[:, drop:]
        extras = {k: (v[:, drop:] if v.shape[:2] == (n, t) else v) for k, v in extras.items()}
    record = {"original": {"sound_speed": survey.meta.sound_speed,
                           "level_heights_m": levels.heights.round(6).tolist()},
              "correction": corr.model_dump(), "dropped_leading_samples": drop, **(note or {})}
    attrs = {**survey.meta.attrs, "autofocus": json.dumps(record),
             "autofocus_original_sound_speed": float(survey.meta.sound_speed)}
    meta = survey.meta.model_copy(update={"sound_speed": corr.sound_speed, "attrs": attrs})
    return dataclasses.replace(survey, tx=geo.tx, rx=geo.rx, t0=t0, samples=samples, meta=meta,
                               extras=extras, shape=(n, t - drop))


# ------------------------------------------------------------------------------------------
# the search


class _Problem:
    """Maps a parameter vector (in units of each parameter's coarse step) to an image cost."""

    def __init__(self, survey: Survey, signals: np.ndarray, cfg: AutofocusConfig, levels: HeightLevels,
                 pings: np.ndarray, points: np.ndarray):
        self.survey, self.cfg, self.levels = survey, cfg, levels
        self.c0 = survey.meta.sound_speed
        self.full = QuickImager(survey, signals, pings)
        self.coarse = QuickImager(survey, signals, pings[::2]) if len(pings) >= 16 else self.full
        self.points = points
        self.points_coarse = points
        names: list[tuple[str, int]] = []
        # knots of the piecewise-linear level_z (heights of the levels' TX), when asked for
        self.knots = (np.linspace(levels.heights.min(), levels.heights.max(), cfg.level_z_knots)
                      if cfg.level_z_knots else None)
        for p in cfg.parameters:
            if p == "level_z":
                count = levels.count if self.knots is None else len(self.knots)
                names += [("level_z", k) for k in range(1, count)]
            else:
                names.append((p, 0))
        self.names = names
        self.steps = np.array([self._step(p) for p, _ in names])
        self.spans = np.array([self._span(p) for p, _ in names])
        self.evaluations = 0

    def _step(self, p: str) -> float:
        c = self.cfg
        return {"sound_speed": c.sound_speed_step, "range_offset": c.range_offset_step_m,
                "level_z": c.level_z_step_m, "radius": c.radius_step_m}[p]

    def _span(self, p: str) -> float:
        c = self.cfg
        return {"sound_speed": c.sound_speed_span, "range_offset": c.range_offset_span_m,
                "level_z": c.level_z_span_m, "radius": c.radius_span_m}[p]

    def correction(self, x: np.ndarray) -> Correction:
        v = x * self.steps
        eps = dr = drho = 0.0
        count = self.levels.count if self.knots is None else len(self.knots)
        dz = [0.0] * count if "level_z" in self.cfg.parameters else []
        for (p, k), val in zip(self.names, v, strict=True):
            if p == "sound_speed":
                eps = float(val)
            elif p == "range_offset":
                dr = float(val)
            elif p == "radius":
                drho = float(val)
            else:
                dz[k] = float(val)
        if dz and self.knots is not None:
            # the lowest knot is held at 0 like the lowest level; heights between knots interpolate
            dz = np.interp(self.levels.heights, self.knots, dz).tolist()
        return Correction(sound_speed=self.c0 * (1 + eps), range_offset_m=dr, level_z_m=tuple(dz),
                          radius_offset_m=drho)

    def cost(self, x: np.ndarray, coarse: bool = False) -> float:
        imager = self.coarse if coarse else self.full
        idx = imager.pings
        geo = corrected_geometry(self.survey.tx[idx], self.survey.rx[idx], self.survey.t0[idx],
                                 self.levels.index[idx], self.c0, self.correction(np.asarray(x)))
        self.evaluations += 1
        return focus_cost(imager.image(geo, self.points), self.cfg.measure)


def _search_points(survey: Survey, cfg: AutofocusConfig, plane_z: float | None) -> np.ndarray:
    box = survey.meta.scene_box
    if plane_z is not None:
        return plane_grid(box, plane_z, cfg.pixels).points()
    return Grid.over(box, max(cfg.pixels // 2, 8)).points()


def autofocus(survey: Survey, signals: np.ndarray | None = None, config: AutofocusConfig | None = None,
              progress: ProgressFn = no_progress) -> AutofocusResult:
    """Estimate ``config.parameters`` by maximising image sharpness (see the module docstring).

    Args:
        survey: the survey (samples loaded).
        signals: (N, T) complex signals to image; default the Wiener-deconvolved samples.
    Returns:
        :class:`AutofocusResult`; :func:`apply_correction` writes its correction into a survey.
    """
    import time

    from scipy.optimize import minimize

    cfg = config or AutofocusConfig()
    t_start = time.perf_counter()
    if survey.samples is None:
        raise ShsasError("autofocus: the survey's samples were not loaded")
    if signals is None:
        from .deconv import deconvolve

        signals = deconvolve(survey)
    levels = height_levels(survey.tx)
    notes: list[str] = []
    if "level_z" in cfg.parameters and levels.count < 2:
        raise ShsasError("autofocus: level_z needs at least two height levels; this survey has one (its "
                         "height is not separable from the image plane's) (fix: leave level_z out of --params)")
    if "radius" in cfg.parameters:
        _check_circular(survey)
    elev = elevation_info(survey)
    plane_z = cfg.plane_z
    pings = np.unique(np.linspace(0, survey.num_pings - 1, min(cfg.max_pings, survey.num_pings)).round()
                      .astype(np.int64))
    if elev.planar:
        if plane_z is None:
            plane_z = focus_height(survey, signals, measure=cfg.measure, pings=pings)
            notes.append(f"{elev.kind} survey: imaged in the plane of best focus under the input geometry, "
                         f"z = {plane_z:.4f} m; the plane's height, the range offset and the sound speed "
                         "trade off on such a survey, so give --plane-z (the scene plane's known height) "
                         "for an estimate that means something")
        if "sound_speed" in cfg.parameters and "range_offset" in cfg.parameters:
            notes.append("sound speed and range offset are nearly degenerate on a planar survey: the joint "
                         "estimate may slide along the valley (docs/usage.md)")
    else:
        plane_z = None
    problem = _Problem(survey, np.asarray(signals), cfg, levels, pings, _search_points(survey, cfg, plane_z))
    dim = len(problem.names)
    x = np.zeros(dim)
    progress(0.0, "autofocus", {})
    cost_before = problem.cost(x)
    # coarse: each parameter in turn over its grid, on the coarse image
    for _ in range(cfg.rounds):
        for i in range(dim):
            half = round(problem.spans[i] / problem.steps[i])
            grid = np.arange(-half, half + 1, dtype=float)
            costs = []
            for g in grid:
                xi = x.copy()
                xi[i] = g
                costs.append(problem.cost(xi, coarse=True))
            x[i] = grid[int(np.argmin(costs))]
            progress(0.1 + 0.5 * (i + 1) / dim, "autofocus", {"cost": float(min(costs))})
    # fine: joint Powell on the full search image, within one coarse step of the coarse optimum
    bounds = [(xi - 1.5, xi + 1.5) for xi in x]
    res = minimize(problem.cost, x, method="Powell", bounds=bounds,
                   options={"xtol": cfg.tolerance, "ftol": 1e-9})
    x_best = res.x if res.fun <= problem.cost(x) else x
    cost_after = problem.cost(x_best)
    progress(1.0, "autofocus", {"cost": cost_after})
    return AutofocusResult(
        correction=problem.correction(np.asarray(x_best)), original_sound_speed=survey.meta.sound_speed,
        level_heights_m=levels.heights.round(6).tolist(), parameters=list(cfg.parameters), measure=cfg.measure,
        plane_z=plane_z, cost_before=cost_before, cost_after=cost_after, evaluations=problem.evaluations,
        seconds=time.perf_counter() - t_start, notes=notes)
