"""Autofocus: estimate survey parameters that are wrong or unknown from the image's sharpness.

A sonar image is sharpest when the geometry used to form it is the one the data were recorded
with. :func:`autofocus` searches the parameters below for the sharpest (lowest-entropy, or
highest-contrast: :mod:`shsas_core.imaging.sharpness`) fast low-resolution backprojection
(:mod:`shsas_core.imaging.quicklook`) and :func:`apply_correction` writes them into the survey:

* ``sound_speed``: ``c``, searched as a relative change of the survey's value;
* ``range_offset``: a one-way range offset ``dr``: echoes recorded ``2 dr / c`` late (an
  unremoved delay); corrected by moving ``t0`` earlier by that time;
* ``level_z``: a height offset per height level (:func:`shsas_core.data.geometry.height_levels`), the
  lowest level held at zero: a common height shift of every sensor only moves the image. With
  ``level_z_knots = K`` the offsets are a piecewise-linear function of the level's height with K
  evenly spaced knots (K − 1 unknowns; K = 2 is a wrong height step): a scan of 150 levels is
  then searched with a handful of parameters instead of 149;
* ``radius``: the TX/RX circle radius about the z axis (circular scans): both sensors move
  radially by ``dρ``.

Search (coarse to fine): each parameter in turn over a grid (steps below the width of the cost's
minimum) on a coarse image of every second selected ping, then a joint bounded Powell
refinement (``scipy.optimize.minimize``) on the full search image.

What the data identify (:func:`identified`, the one rule): every unknown gets two figures,

* its *curvature*: how much the cost rises one resolution step either side of the optimum
  (the step that moves an echo by one range cell ``c / 2B``; the other unknowns re-optimised,
  from the cost's Hessian), in the measure's units: nats of entropy, where ``e^κ − 1`` is the
  relative growth of the image's effective pixel count;
* its *spread*: the RMS difference between the estimates from ``subsets`` disjoint interleaved
  ping subsets, each searched on its own, and the all-ping estimate.

A correction is applied only where the curvature is at least :data:`MIN_CURVATURE`, the spread
at most :data:`MAX_SPREAD_RATIO` of the correction and :data:`MAX_SPREAD_STEPS` of a resolution
step, the correction at least
:data:`MIN_CHANGE_STEPS` of a resolution step and the estimate inside the search range; otherwise the input value is kept and the result says why. A perturbation the data cannot
resolve is therefore left as it came, never moved further off.

Defaults (:func:`default_parameters`): on a single-height (or elevation-poor) survey, sound
speed, range offset and the image plane's height trade off along one valley of the cost, so
such a survey is searched in one plane for ``sound_speed`` alone unless more is asked for; 3-D
surveys estimate ``sound_speed`` and ``range_offset`` together. ``radius`` is nearly degenerate
with ``range_offset`` for a scene near the axis.
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import ProgressFn, no_progress
from shsas_core.data.geometry import ElevationInfo, HeightLevels, elevation_info, height_levels
from shsas_core.data.survey import Survey
from shsas_core.data.volume import Grid
from shsas_core.imaging.planar import FocusResult, find_focus, plane_grid
from shsas_core.imaging.quicklook import Geometry, QuickImager
from shsas_core.imaging.sharpness import Sharpness, focus_cost

Parameter = Literal["sound_speed", "range_offset", "level_z", "radius"]
PARAMETERS: tuple[str, ...] = ("sound_speed", "range_offset", "level_z", "radius")
#: Horizontal sensor radii about the z axis may vary this much (relative) for ``radius``.
CIRCULAR_TOLERANCE = 0.01
#: Identifiability rule, part 1: the cost must rise at least this much (nats of entropy, or of
#: log contrast) one resolution step either side of the optimum: 1 % more effective pixels.
MIN_CURVATURE = 0.01
#: Identifiability rule, part 2: the subsets' spread may be at most this fraction of the
#: correction (a correction five times its own scatter).
MAX_SPREAD_RATIO = 0.2
#: Identifiability rule, part 2b: the subsets must also agree to this fraction of a resolution
#: step (an estimate that moves further between halves of the data is not pinned down).
MAX_SPREAD_STEPS = 0.1
#: Identifiability rule, part 3: a change under this fraction of a resolution step is no change
#: (below what the search resolves, and not worth a new survey file).
MIN_CHANGE_STEPS = 0.05
#: Each ping subset holds at least this many pings (fewer: no spread, nothing identified).
MIN_SUBSET_PINGS = 8
#: Profile curvatures (other unknowns re-optimised) from a full Hessian up to this many unknowns;
#: above it the per-axis curvature (a per-level ``level_z`` has one unknown per level).
MAX_HESSIAN_UNKNOWNS = 4


class AutofocusConfig(BaseModel):
    """What :func:`autofocus` searches and how."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    parameters: tuple[Parameter, ...] | None = Field(
        None, min_length=1, description="None: default_parameters(survey) (one unknown on single-height surveys)")
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
    subsets: int = Field(3, ge=2, le=8, description="disjoint interleaved ping subsets searched on their own "
                         "for each estimate's spread")


class Correction(BaseModel):
    """Estimated parameters (the survey's own values where not searched)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sound_speed: float = Field(gt=0, description="m/s")
    range_offset_m: float = Field(0.0, description="one-way range offset removed, m (t0 moved by -2 dr / c)")
    level_z_m: tuple[float, ...] = Field((), description="height offset added to each level's sensors, m")
    radius_offset_m: float = Field(0.0, description="radial move of TX and RX about the z axis, m")


class Identifiability(BaseModel):
    """How well the data pin down one unknown, and what was done with it (values in ``unit``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(description="sound_speed, range_offset, radius, or level_z[k] (k: level or knot)")
    unit: str
    input: float = Field(description="the survey's value: c in m/s, 0 for an offset")
    estimate: float = Field(description="the all-ping estimate")
    subset_estimates: list[float] = Field(description="each ping subset's own estimate")
    spread: float | None = Field(description="RMS of subset estimate - estimate; None: too few pings")
    resolution_step: float = Field(description="the change that moves an echo by one range cell c/2B")
    curvature: float = Field(description="cost rise one resolution step either side of the optimum")
    identified: bool = Field(description="the rule held: the correction was applied")
    value: float = Field(description="the value written: the estimate if identified, else the input")
    message: str = Field(description="what was done and why, in plain words")


class AutofocusResult(BaseModel):
    """What the search found and what of it was applied."""

    model_config = ConfigDict(extra="forbid")

    correction: Correction = Field(description="what apply_correction writes: identified unknowns only")
    estimate: Correction = Field(description="the all-ping optimum, identified or not")
    identifiability: list[Identifiability]
    summary: str = Field(description="one plain-words line: what was corrected, what was kept")
    original_sound_speed: float
    level_heights_m: list[float] = Field(description="TX height of each level before correction")
    parameters: list[str]
    parameters_default: bool = Field(description="the parameters were chosen by default_parameters")
    measure: str
    plane_z: float | None = Field(description="height of the imaged plane (planar surveys), m")
    cost_before: float
    cost_after: float = Field(description="cost with the applied correction")
    cost_estimate: float = Field(description="cost at the all-ping estimate")
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


def default_parameters(elevation: ElevationInfo) -> tuple[Parameter, ...]:
    """What :func:`autofocus` estimates when not told: one unknown on a survey that images one
    plane (sound speed, range offset and the plane's height trade off there, docs/usage.md),
    sound speed and range offset together on a 3-D survey."""
    return ("sound_speed",) if elevation.planar else ("sound_speed", "range_offset")


def identified(curvature: float, spread: float | None, correction: float, step: float,
               at_edge: bool) -> tuple[bool, str]:
    """The identifiability rule (module docstring): (applied?, the reason in plain words).

    ``spread``, ``correction`` and the resolution ``step`` in the same unit; ``at_edge``: the
    estimate lies on the search range's edge.
    """
    if abs(correction) < MIN_CHANGE_STEPS * step:
        return False, (f"the sharpest image is within {MIN_CHANGE_STEPS:g} of a resolution step ({step:.3g}) "
                       "of the input value, so there is nothing to correct")
    if at_edge:
        return False, "the estimate lies on the edge of the search range, so the optimum was not found"
    if curvature < MIN_CURVATURE:
        return False, (f"the image barely changes over one resolution step (cost rise {curvature:.3g} < "
                       f"{MIN_CURVATURE:g}), so the data do not identify it")
    if spread is None:
        return False, "too few pings to compare estimates from separate ping subsets"
    if spread > MAX_SPREAD_STEPS * step:
        return False, (f"the ping subsets' estimates scatter by {spread:.3g}, more than {MAX_SPREAD_STEPS:g} of a "
                       f"resolution step ({step:.3g}), so the data do not pin it down")
    if spread > MAX_SPREAD_RATIO * abs(correction):
        return False, (f"the ping subsets' estimates scatter by {spread:.3g}, not small against the change "
                       f"of {correction:+.3g} (they must scatter less than {MAX_SPREAD_RATIO:.2g} of it), so "
                       "the data do not identify a change")
    return True, (f"identified: cost rise {curvature:.3g} per resolution step, subsets' scatter {spread:.3g} "
                  f"against a change of {correction:+.3g}")


class _Problem:
    """Maps a parameter vector (in units of each parameter's coarse step) to an image cost."""

    def __init__(self, survey: Survey, cfg: AutofocusConfig, parameters: tuple[str, ...], levels: HeightLevels,
                 points: np.ndarray):
        self.survey, self.cfg, self.levels, self.parameters = survey, cfg, levels, parameters
        self.c0 = survey.meta.sound_speed
        self.points = points
        names: list[tuple[str, int]] = []
        # knots of the piecewise-linear level_z (heights of the levels' TX), when asked for
        self.knots = (np.linspace(levels.heights.min(), levels.heights.max(), cfg.level_z_knots)
                      if cfg.level_z_knots else None)
        for p in parameters:
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

    def resolution_steps(self) -> np.ndarray:
        """Each unknown's change that moves an echo by one range cell ``c / 2B``, in its own
        search units (the two-way path over the scene's centre sets the sound speed's)."""
        s = self.survey
        cell = s.meta.sound_speed / (2 * s.meta.pulse.bandwidth)
        centre = self.points.mean(0)
        path = np.linalg.norm(s.tx - centre, axis=1) + np.linalg.norm(s.rx - centre, axis=1)
        mid = 0.5 * (s.tx + s.rx) - centre
        sin_dep = float(np.mean(np.abs(mid[:, 2]) / np.linalg.norm(mid, axis=1)))
        cos_dep = math.sqrt(max(1 - sin_dep ** 2, 0.0))
        # a sound-speed error scales the two-way path; a height error changes it by 2 dz sin(dep),
        # a radial one by 2 dρ cos(dep); both floored so a degenerate angle gives a finite step
        phys = {"sound_speed": 2 * cell / float(path.mean()), "range_offset": cell,
                "level_z": cell / max(sin_dep, 0.05), "radius": cell / max(cos_dep, 0.05)}
        return np.array([phys[p] for p, _ in self.names]) / self.steps

    def correction(self, x: np.ndarray) -> Correction:
        v = x * self.steps
        eps = dr = drho = 0.0
        count = self.levels.count if self.knots is None else len(self.knots)
        dz = [0.0] * count if "level_z" in self.parameters else []
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

    def physical(self, x: np.ndarray) -> list[tuple[str, str, float, float]]:
        """(name, unit, input value, value at ``x``) of each unknown."""
        out = []
        for (p, k), v in zip(self.names, x * self.steps, strict=True):
            if p == "sound_speed":
                out.append(("sound_speed", "m/s", self.c0, self.c0 * (1 + float(v))))
            else:
                out.append((p if p != "level_z" else f"level_z[{k}]", "m", 0.0, float(v)))
        return out

    def cost(self, x: np.ndarray, imager: QuickImager, plane_dz: float = 0.0) -> float:
        """Cost of the image for unknowns ``x``, its points raised by ``plane_dz`` (m)."""
        idx = imager.pings
        geo = corrected_geometry(self.survey.tx[idx], self.survey.rx[idx], self.survey.t0[idx],
                                 self.levels.index[idx], self.c0, self.correction(np.asarray(x)))
        pts = self.points
        if plane_dz:
            pts = pts + np.array([0.0, 0.0, plane_dz])
        self.evaluations += 1
        return focus_cost(imager.image(geo, pts), self.cfg.measure)

    def search(self, full: QuickImager, coarse: QuickImager, progress: ProgressFn | None = None) -> np.ndarray:
        """Coarse grid per unknown (``coarse`` image), then joint bounded Powell (``full``)."""
        from scipy.optimize import minimize

        dim = len(self.names)
        x = np.zeros(dim)
        for _ in range(self.cfg.rounds):
            for i in range(dim):
                half = round(self.spans[i] / self.steps[i])
                grid = np.arange(-half, half + 1, dtype=float)
                costs = []
                for g in grid:
                    xi = x.copy()
                    xi[i] = g
                    costs.append(self.cost(xi, coarse))
                x[i] = grid[int(np.argmin(costs))]
                if progress is not None:
                    progress(0.05 + 0.35 * (i + 1) / dim, "autofocus", {"cost": float(min(costs))})
        # fine: joint Powell on the full image, within 1.5 coarse steps of the coarse optimum
        # and inside the search range
        lim = np.round(self.spans / self.steps)
        bounds = [(max(xi - 1.5, -h), min(xi + 1.5, h)) for xi, h in zip(x, lim, strict=True)]
        res = minimize(lambda v: self.cost(v, full), x, method="Powell", bounds=bounds,
                       options={"xtol": self.cfg.tolerance, "ftol": 1e-9})
        return res.x if res.fun <= self.cost(x, full) else x

    def curvatures(self, x: np.ndarray, imager: QuickImager, f0: float, plane_free: bool) -> np.ndarray:
        """Cost rise one resolution step either side of ``x`` per unknown: the profile value
        ``1 / (2 (H⁻¹)ᵢᵢ)`` of the Hessian ``H`` in resolution steps (other unknowns free) up to
        :data:`MAX_HESSIAN_UNKNOWNS` unknowns, else the per-axis ``Hᵢᵢ / 2``; 0 where the
        Hessian is not positive definite (a flat or saddle direction). ``plane_free``: the image
        plane's height was chosen by the search, not given, so it is one more free direction of
        ``H`` (its step: a range cell over the sine of the depression angle): an unknown that
        only trades off against the plane's height is not identified."""
        r = self.resolution_steps()
        dim = len(r)
        full_dim = dim + int(plane_free)

        def f(u: np.ndarray) -> float:
            dz = float(u[dim]) * self.plane_step() if plane_free else 0.0
            return self.cost(x + u[:dim] * r, imager, dz)

        eye = np.eye(full_dim)
        h = np.zeros((full_dim, full_dim))
        for i in range(full_dim):
            h[i, i] = f(eye[i]) + f(-eye[i]) - 2 * f0
        if full_dim == 1 or full_dim > MAX_HESSIAN_UNKNOWNS:
            return np.maximum(np.diag(h)[:dim] / 2, 0.0)
        for i in range(full_dim):
            for j in range(i + 1, full_dim):
                h[i, j] = h[j, i] = (f(eye[i] + eye[j]) - f(eye[i] - eye[j]) - f(-eye[i] + eye[j])
                                     + f(-eye[i] - eye[j])) / 4
        try:
            np.linalg.cholesky(h)
        except np.linalg.LinAlgError:
            return np.zeros(dim)
        return 1 / (2 * np.diag(np.linalg.inv(h))[:dim])

    def plane_step(self) -> float:
        """The image plane's height change that moves an echo by one range cell, m."""
        s = self.survey
        cell = s.meta.sound_speed / (2 * s.meta.pulse.bandwidth)
        mid = 0.5 * (s.tx + s.rx) - self.points.mean(0)
        sin_dep = float(np.mean(np.abs(mid[:, 2]) / np.linalg.norm(mid, axis=1)))
        return cell / max(sin_dep, 0.05)


def _search_points(survey: Survey, cfg: AutofocusConfig, plane_z: float | None) -> np.ndarray:
    box = survey.meta.scene_box
    if plane_z is not None:
        return plane_grid(box, plane_z, cfg.pixels).points()
    return Grid.over(box, max(cfg.pixels // 2, 8)).points()


def search_plane(survey: Survey, signals: np.ndarray, cfg: AutofocusConfig, pings: np.ndarray) -> FocusResult:
    """The plane a planar survey is searched in when ``cfg.plane_z`` is not given: the plane of
    best focus under the input geometry (:func:`shsas_core.imaging.planar.find_focus`), or the search's
    edge with ``found`` False when the data hold no focus. Its images are compiled: the
    autofocus's own imaging compiles the kernel in this process anyway."""
    return find_focus(survey, signals, measure=cfg.measure, pings=pings, compiled=True)


def autofocus(survey: Survey, signals: np.ndarray | None = None, config: AutofocusConfig | None = None,
              progress: ProgressFn = no_progress) -> AutofocusResult:
    """Estimate ``config.parameters`` by maximising image sharpness and keep only what the data
    identify (see the module docstring).

    Args:
        survey: the survey (samples loaded).
        signals: (N, T) complex signals to image; default the Wiener-deconvolved samples.
    Returns:
        :class:`AutofocusResult`; :func:`apply_result` writes its applied correction and its
        identifiability into a survey.
    """
    import time

    cfg = config or AutofocusConfig()
    t_start = time.perf_counter()
    if survey.samples is None:
        raise ShsasError("autofocus: the survey's samples were not loaded")
    if signals is None:
        from shsas_core.signal.sources import signals_for

        signals = signals_for(survey, "deconvolve").values
    signals = np.asarray(signals)
    levels = height_levels(survey.tx)
    elev = elevation_info(survey)
    parameters = cfg.parameters or default_parameters(elev)
    notes: list[str] = []
    if cfg.parameters is None:
        notes.append(f"{elev.kind} survey: estimating {', '.join(parameters)} (the default for such a survey; "
                     "name others with --params)")
    if "level_z" in parameters and levels.count < 2:
        raise ShsasError("autofocus: level_z needs at least two height levels; this survey has one (its "
                         "height is not separable from the image plane's) (fix: leave level_z out of --params)")
    if "radius" in parameters:
        _check_circular(survey)
    plane_z = cfg.plane_z
    pings = np.unique(np.linspace(0, survey.num_pings - 1, min(cfg.max_pings, survey.num_pings)).round()
                      .astype(np.int64))
    progress(0.0, "autofocus", {})
    if elev.planar:
        if plane_z is None:
            focus = search_plane(survey, signals, cfg, pings)
            plane_z = focus.z
            if not focus.found:
                notes.append(f"no plane of focus found ({focus.reason}); the search image lies at the search's "
                             f"edge, z = {plane_z:.4f} m, so give --plane-z (the scene plane's known height)")
            notes.append(f"{elev.kind} survey: imaged in the plane of best focus under the input geometry, "
                         f"z = {plane_z:.4f} m; the plane's height, the range offset and the sound speed "
                         "trade off on such a survey, so give --plane-z (the scene plane's known height) "
                         "for an estimate that means something")
        if "sound_speed" in parameters and "range_offset" in parameters:
            notes.append("sound speed and range offset are nearly degenerate on a planar survey: expect them "
                         "to be reported as not identified (docs/usage.md)")
    else:
        plane_z = None
    problem = _Problem(survey, cfg, parameters, levels, _search_points(survey, cfg, plane_z))
    full = QuickImager(survey, signals, pings)
    coarse = QuickImager(survey, signals, pings[::2]) if len(pings) >= 16 else full
    zero = np.zeros(len(problem.names))
    cost_before = problem.cost(zero, full)
    x_best = problem.search(full, coarse, progress)
    cost_estimate = problem.cost(x_best, full)
    # the same search on each disjoint interleaved subset of the pings, on its own
    k = min(cfg.subsets, len(pings) // MIN_SUBSET_PINGS)
    subset_x = []
    for s in range(k if k >= 2 else 0):
        sub = QuickImager(survey, signals, pings[s::k])
        subset_x.append(problem.search(sub, sub))
        progress(0.4 + 0.45 * (s + 1) / k, "autofocus", {})
    curv = problem.curvatures(x_best, full, cost_estimate, plane_free=elev.planar and cfg.plane_z is None)
    lim = np.round(problem.spans / problem.steps)
    est = problem.physical(x_best)
    subs = [problem.physical(x) for x in subset_x]
    res_phys = [abs(b[3] - b[2]) for b in problem.physical(problem.resolution_steps())]
    report: list[Identifiability] = []
    keep = np.zeros(len(est), dtype=bool)
    for i, (name, unit, inp, val) in enumerate(est):
        sub_vals = [s[i][3] for s in subs]
        spread = float(np.sqrt(np.mean((np.asarray(sub_vals) - val) ** 2))) if sub_vals else None
        at_edge = bool(abs(x_best[i]) >= lim[i] - 1e-6)
        ok, why = identified(float(curv[i]), spread, val - inp, res_phys[i], at_edge)
        keep[i] = ok
        kept = f"corrected from {inp:.6g} to {val:.6g} {unit}" if ok else f"kept at {inp:.6g} {unit}"
        report.append(Identifiability(
            name=name, unit=unit, input=inp, estimate=val, subset_estimates=sub_vals, spread=spread,
            resolution_step=res_phys[i], curvature=float(curv[i]), identified=ok, value=val if ok else inp,
            message=f"{name} {kept}: {why}" + ("" if ok else f" (the sharpest image was at {val:.6g} {unit})")))
    x_applied = np.where(keep, x_best, 0.0)
    if keep.any() and not keep.all():
        notes.append("the identified corrections were estimated together with the unidentified ones, which "
                     "are kept at their input values")
    cost_after = problem.cost(x_applied, full) if keep.any() else cost_before
    fixed = [r.name for r in report if r.identified]
    kept_names = [r.name for r in report if not r.identified]
    summary = "; ".join(filter(None, [
        f"corrected {', '.join(fixed)}" if fixed else "",
        f"kept {', '.join(kept_names)} at the input value{'s' if len(kept_names) > 1 else ''} (not identified "
        "by the data)" if kept_names else ""]))
    progress(1.0, "autofocus", {"cost": cost_after})
    return AutofocusResult(
        correction=problem.correction(x_applied), estimate=problem.correction(x_best), identifiability=report,
        summary=f"autofocus: {summary}", original_sound_speed=survey.meta.sound_speed,
        level_heights_m=levels.heights.round(6).tolist(), parameters=list(parameters),
        parameters_default=cfg.parameters is None, measure=cfg.measure, plane_z=plane_z, cost_before=cost_before,
        cost_after=cost_after, cost_estimate=cost_estimate, evaluations=problem.evaluations,
        seconds=time.perf_counter() - t_start, notes=notes)


def apply_result(survey: Survey, result: AutofocusResult) -> Survey:
    """:func:`apply_correction` of ``result.correction`` with the identifiability of every unknown
    in ``meta.attrs["autofocus"]`` and the plain-words summary in ``meta.attrs["autofocus_summary"]``
    (which reaches ``shsas info`` and the reconstruction report with the survey's attrs)."""
    note = {"measure": result.measure, "plane_z": result.plane_z, "cost_before": result.cost_before,
            "cost_after": result.cost_after, "estimate": result.estimate.model_dump(),
            "identifiability": [r.model_dump() for r in result.identifiability], "summary": result.summary}
    out = apply_correction(survey, result.correction, note=note)
    attrs = {**out.meta.attrs, "autofocus_summary": result.summary}
    return dataclasses.replace(out, meta=out.meta.model_copy(update={"attrs": attrs}))
