"""Results that say when they failed: checks of a finished method's volume and fit.

A reconstruction can run to the end and still be useless. Three failures are common enough, and
cheap enough to detect, that no result should leave the pipeline without being checked for them:

* ``collapsed`` — the volume is (near-)constant: nothing was reconstructed, and after
  normalisation whatever is extracted is rounding noise. Measure: the relative spread
  ``(max - min) / max`` of the magnitude ``|values|`` (0 for an all-zero or constant volume).
* ``box_filling`` — the volume at or above the extraction level τ fills a large share of the
  scene box instead of tracing a surface: a fog of density, not an object. Measure: voxels at or
  above τ / grid voxels (the whole cloud of a threshold extraction; the ridge extraction's
  candidates start lower, at half of τ, and go through its contrast test).
* ``surface_unclear`` — the ridge extraction's surface test (its local contrast, module doc of
  :mod:`shsas_core.evaluation.extract`) kept a small share of the image's ridge: its points over
  the ridge points at or above τ (the same sheet without the test). The test holds a surface
  against the mean of a window around it; where the image is too blurred for that (a narrow band:
  the echo's mainlobe fills the window) or holds structured clutter (aliasing lobes of a large
  box), it keeps little of anything, and the cloud misses much of the surface. Measure: that share.
* ``loss_not_falling`` — the fit's data loss (the ToF term, a relative residual: 1.0 = predicting
  zeros) ended where it started. Measure: mean data loss over the last :data:`LOSS_WINDOW` of the
  iterations / mean over the first; limit 0.9, lowered when the per-iteration noise is too large
  to show a fall of 10 % (:func:`loss_limit`). A fit that started from a field already explaining
  most of the data (a warm start) is reported only when its loss rose (:data:`LOSS_EXPLAINED`).

* ``mesh_pieces``, ``mesh_area_ratio``, ``mesh_normal_consistency`` — the extracted mesh is not
  one clean surface: it fails a bound of :class:`shsas_core.evaluation.metrics.MeshChecks` on the mesh
  quality the metrics measured (pieces also without ground truth). Checked only when the volume
  passed its own checks: the mesh of a collapsed or fog-filled volume says nothing more.

Each finding is a :class:`ResultWarning` carrying its measure and the limit it crossed, so a
reader can judge how far off the result is. The pipeline stores them in ``report.json``
(``methods[].warnings``) and the HTML report, the CLI prints them, and the service's job status
carries them; a warning never fails the job (the job ran; its result is suspect).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.data.volume import Volume
from shsas_core.evaluation.extract import SURFACE_KEPT_LIMIT

WarningCode = Literal["collapsed", "box_filling", "surface_unclear", "loss_not_falling", "mesh_pieces", "mesh_area_ratio",
                      "mesh_normal_consistency"]

#: ``collapsed`` below this relative spread ``(max - min) / max`` of |values|. Measured on the
#: built-in sphere (docs/usage.md, Warnings): backprojection images span orders of magnitude
#: (spread > 0.999); a neural field starts on a floor, so an early fit spans little (0.077 after
#: 300 envelope iterations, 0.9999 after the demo's 1000), a freshly initialised field is flat to
#: 0.0028, and float32 rounding of a constant leaves ~1e-7. Below 1 % nothing was reconstructed:
#: after normalisation to [0, 1] by that range, τ would cut through initialisation or rounding noise.
COLLAPSE_SPREAD_LIMIT = 0.01
#: ``box_filling`` at or above this share of grid voxels at or above τ. The scene box is the
#: object's bounds plus a small margin, so even a good result can fill a sizeable part of it: the
#: built-in sphere (r = 8 cm in a 20 cm box) is 27 % of its box by volume; backprojections of the
#: built-in shapes and a real AirSAS scan keep 15-31 % of the 64³ voxels above the Otsu level
#: (35 % from a sparse 24-ping circle), the demo's neural fit 16 %. Fogs leave about half of the
#: voxels above it (Otsu splits a unimodal histogram near its middle: 45-52 % measured for
#: under-trained fields); 40 % separates the two.
BOX_FILL_LIMIT = 0.40
#: ``loss_not_falling`` when mean(last window) / mean(first window) of the data loss is at least
#: this: a fit that took the residual down by less than 10 % did not learn the data (fits that
#: learn something measured 0.24-0.79 after 150-1000 iterations, one that learns nothing 0.97).
LOSS_RATIO_LIMIT = 0.90
#: ... or when the fall is within this many standard errors of the ratio: one iteration's data
#: loss is one random batch of pings and bins and scatters by 25-45 % of its mean (measured std /
#: mean of the first window), so a ratio of window means carries noise of its own (about 0.12 for
#: 10-iteration windows). The limit becomes ``min(LOSS_RATIO_LIMIT, 1 - LOSS_NOISE_SIGMAS * se)``:
#: a fall no larger than twice its standard error is not shown to be a fall.
LOSS_NOISE_SIGMAS = 2.0
#: A first window whose mean data loss is below this started from a field that already explains
#: most of the data (1.0 = predicting zeros): a warm start from the backprojection image, 0.16 on
#: the noisy (5 dB) bunny of bench_fidelity.py (seed 1), which the fit took to 0.14: a ratio of
#: 0.83 or 0.89 against a limit of 0.87, on either side by the rounding alone (single-tensor or
#: fused Adam). Such a fit is reported only when its loss rose beyond the ratio's noise
#: (``1 + LOSS_NOISE_SIGMAS * se``): a flat loss there is no failure to learn.
LOSS_EXPLAINED = 0.5
#: Share of the iterations averaged at each end of the loss history.
LOSS_WINDOW = 0.10
#: Fewer iterations than this are not judged: windows of fewer than 10 iterations give a
#: standard error too rough to set the limit by.
LOSS_MIN_ITERS = 100


class ResultWarning(BaseModel):
    """One way a finished result looks failed, with the number that says so.

    ``measure`` and ``limit`` share a unit (see the codes in the module doc): the result was
    flagged because ``measure`` fell below (``collapsed``) or reached (``box_filling``,
    ``loss_not_falling``) ``limit``; a mesh check's measure lies outside its bound.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    code: WarningCode
    message: str = Field(description="what looks wrong, in words")
    measure: float = Field(description="the measured value (see code)")
    limit: float = Field(description="the limit it crossed")

    def line(self, method: str) -> str:
        """One line for a terminal or log: ``<method>: <message> (<measure> vs limit <limit>)``."""
        return f"{method}: {self.message} ({self.measure:.3g} vs limit {self.limit:.3g})"


def relative_spread(volume: Volume) -> float:
    """``(max - min) / max`` of the finite, nonzero magnitudes of ``volume``; 0 when none is positive.

    Exact zeros are left out: they are voxels the method did not reconstruct (a neural field is
    empty outside its occupancy mask), so an untrained field inside a mask is as flat as one
    without it. Arithmetic on real data does not land on exactly 0 elsewhere, and a volume that
    is 0 everywhere still measures 0."""
    m = volume.magnitude()
    m = m[np.isfinite(m) & (m != 0)]
    if m.size == 0:
        return 0.0
    hi = float(m.max())
    return (hi - float(m.min())) / hi if hi > 0 else 0.0


def filled_share(volume: Volume, tau: float) -> float:
    """Share of the grid's voxels whose normalised magnitude is at or above ``tau``, in [0, 1]."""
    from shsas_core.evaluation.extract import normalize

    norm = normalize(volume)
    return float(np.count_nonzero(norm >= tau)) / max(norm.size, 1)


def loss_windows(data_loss_history: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The first and the last :data:`LOSS_WINDOW` of the finite losses (at least two each)."""
    h = np.asarray([v for v in data_loss_history if math.isfinite(v)], dtype=np.float64)
    k = max(2, math.floor(len(h) * LOSS_WINDOW))
    return h[:k], h[-k:]


def loss_ratio(data_loss_history: Sequence[float]) -> tuple[float, float] | None:
    """``(ratio, standard error)``: ratio = mean(last :data:`LOSS_WINDOW`) / mean(first) of the
    finite losses, its standard error propagated from the two windows' standard errors of the
    mean. None when there are fewer than :data:`LOSS_MIN_ITERS` or the first mean is not positive."""
    if sum(math.isfinite(v) for v in data_loss_history) < LOSS_MIN_ITERS:
        return None
    a, b = loss_windows(data_loss_history)
    k = len(a)
    first, last = float(a.mean()), float(b.mean())
    if not first > 0:
        return None
    ratio = last / first
    # relative standard errors of the two means add in quadrature (independent batches)
    rel = math.hypot(float(a.std(ddof=1)) / (first * math.sqrt(k)),
                     float(b.std(ddof=1)) / (max(last, 1e-30) * math.sqrt(k)))
    return ratio, ratio * rel


def loss_limit(stderr: float) -> float:
    """The ratio at or above which the loss did not fall, for a ratio with standard error ``stderr``."""
    return max(0.0, min(LOSS_RATIO_LIMIT, 1.0 - LOSS_NOISE_SIGMAS * stderr))


def surface_kept_share(volume: Volume, tau: float, points: int, resolution: float | None) -> float:
    """``points`` (the ridge cloud's size) over the number of ridge points of ``volume`` at or
    above ``tau``, found at the extraction's own smoothing (``resolution``: the survey's range
    resolution, m, as :func:`~shsas_core.evaluation.extract.extract` takes it); inf when that
    ridge is empty."""
    from shsas_core.evaluation.extract import ExtractConfig, normalize, ridge_sigma
    from shsas_core.evaluation.ridge import ridge

    norm = normalize(volume)
    grid = volume.grid
    sigma = ridge_sigma(grid.spacing, ExtractConfig(), resolution)
    full = len(ridge(norm, norm >= tau, np.asarray(grid.box_min), grid.spacing, sigma))
    return points / full if full else math.inf


def volume_warnings(volume: Volume, tau: float, ridge_points: int | None = None,
                    resolution: float | None = None) -> list[ResultWarning]:
    """Check a method's volume and its extraction.

    Args:
        volume: the reconstructed volume (complex or real, ``grid.shape``).
        tau: the normalised iso level used for extraction.
        ridge_points: the size of its ridge cloud (None: a threshold cloud, no surface test).
        resolution: the survey's range resolution ``c / 2B``, m, the ridge's scale (None: the
            extraction's default in voxels).
    Returns:
        ``collapsed`` or ``box_filling`` warnings (at most one: the cloud of a collapsed volume
        is rounding noise, so its size says nothing more), else ``surface_unclear`` or none.
    """
    spread = relative_spread(volume)
    if spread < COLLAPSE_SPREAD_LIMIT:
        return [ResultWarning(
            code="collapsed", measure=spread, limit=COLLAPSE_SPREAD_LIMIT,
            message="the volume is near-constant (relative spread (max-min)/max of |values|): "
                    "nothing was reconstructed")]
    share = filled_share(volume, tau)
    if share >= BOX_FILL_LIMIT:
        n = round(share * volume.grid.num_voxels)
        return [ResultWarning(
            code="box_filling", measure=share, limit=BOX_FILL_LIMIT,
            message=f"the extracted cloud fills the scene box ({n} of {volume.grid.num_voxels} "
                    f"voxels at or above τ = {tau:.3f}): a fog, not a surface")]
    if ridge_points is not None:
        kept = surface_kept_share(volume, tau, ridge_points, resolution)
        if kept < SURFACE_KEPT_LIMIT:
            res = "" if resolution is None else f" (range resolution {1e3 * resolution:.0f} mm)"
            return [ResultWarning(
                code="surface_unclear", measure=kept, limit=SURFACE_KEPT_LIMIT,
                message=f"the surface test kept {ridge_points} points, {kept:.0%} of the image's ridge at "
                        f"or above τ: the image is too blurred{res} or holds structured clutter "
                        "(sidelobes, aliasing lobes) for its surface to stand out, and the cloud may miss "
                        "much of it; a scene box closer to the object leaves such lobes out, and "
                        "--surface threshold keeps every voxel at or above τ instead")]
    return []


def fit_warnings(data_loss_history: Sequence[float]) -> list[ResultWarning]:
    """Check a neural fit's data-loss history (one value per iteration, from iteration 0).

    Returns:
        ``[loss_not_falling]`` when the late-to-early ratio reaches :func:`loss_limit` (0.9, lower
        when the loss is too noisy to show a smaller fall), or, for a fit whose first window was
        already below :data:`LOSS_EXPLAINED`, when the ratio exceeds 1 by more than its noise;
        else ``[]`` (also when the history is too short to judge).
    """
    found = loss_ratio(data_loss_history)
    if found is None:
        return []
    ratio, se = found
    pct = round(100 * LOSS_WINDOW)
    what = f"(mean of the last {pct} % of iterations / mean of the first {pct} %)"
    if float(loss_windows(data_loss_history)[0].mean()) < LOSS_EXPLAINED:
        limit = 1.0 + LOSS_NOISE_SIGMAS * se
        message = f"the fit's data loss rose {what}: the fit lost part of what its start explained"
    else:
        limit = loss_limit(se)
        message = f"the fit's data loss did not fall {what}: the field did not learn the data"
    if ratio < limit:
        return []
    return [ResultWarning(code="loss_not_falling", measure=ratio, limit=limit, message=message)]


def mesh_warnings(metrics: Mapping[str, float | None], prefix: str = "mesh_") -> list[ResultWarning]:
    """Check the mesh quality in a method's metrics (``<prefix>pieces``, ``<prefix>area_ratio``,
    ``<prefix>normal_consistency``; missing or None keys are not judged) against
    :data:`shsas_core.evaluation.metrics.MESH_CHECKS`.

    Returns:
        One ``mesh_<key>`` warning per failed bound, in that order.
    """
    from shsas_core.evaluation.metrics import mesh_check_failures

    quality = {k[len(prefix):]: v for k, v in metrics.items() if k.startswith(prefix)}
    return [ResultWarning(code=f"mesh_{key}", message=message, measure=measure, limit=limit)  # type: ignore[arg-type]
            for key, message, measure, limit in mesh_check_failures(quality)]
