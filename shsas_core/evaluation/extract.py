"""Turn a reconstructed volume into geometry: a surface point cloud and one mesh per object.

Both backprojection images (complex ``|I|``) and neural fields (``|σ_DC|`` sampled on a grid by
:func:`~shsas_core.neural.fields.volume.field_volume`) arrive here as a :class:`~shsas_core.data.volume.Volume`. The magnitude is
normalised to [0, 1] by its range (``(m - min) / (max - min)``, :func:`normalize`), so the iso
level τ means the same for every method: a neural field's non-zero floor (fog) maps to 0 just
like a backprojection image's near-zero background.

Default (``surface = "ridge"``, ``mesher = "poisson"``), for every method:

1. **Candidates:** voxels at or above ``candidate_share`` x τ (half of it by default: a surface
   lit at grazing angles, like the lower half of an object on the floor, is dimmer than the level
   that splits the box, and the contrast test below, not τ, tells it from background; τ still
   keeps a nearly empty volume's noise peaks out). τ is ``threshold`` when given, else Otsu's
   threshold of the normalised magnitude over the whole grid, clipped to ``[tau_min, tau_max]`` (Otsu splits
   empty space from scatterers without assuming how much of the box the object fills; the clip
   keeps it off the floor of a nearly empty volume and off the single brightest voxel).
2. **Contrast (a CFAR test):** a sonar image's background is not one level: sidelobes and clutter
   are strong next to the object and fall off away from it, so any one level over the whole box
   keeps too much near the object in a large box, or too little in a tight one. Each voxel is
   compared with the mean magnitude in a cube of ``background_window`` metres around it (wider
   than the point-spread function, so a surface is a small part of the cube; cell-averaging
   CFAR), zeros included (``background = "all"``; ``"estimated"`` takes the mean over the
   voxels of non-zero magnitude alone, a candidate measured and not adopted:
   docs/decisions/contrast-over-estimated-voxels.md). For a background of
   Rayleigh-distributed magnitudes (a sum of many random-phase echoes) a voxel exceeds ``k``
   times the local mean with probability ``exp(-π k² / 4)``: ``contrast_strong = 3`` is a
   false-alarm rate of 8.5e-4 per voxel, ``contrast_weak = 2.5`` of 7.4e-3. Ridge voxels at
   ``contrast_weak`` are kept when their connected piece of ridge holds one at
   ``contrast_strong`` (hysteresis, as in Canny's edge detector). An image too coarse or too
   sparse for the test (it keeps fewer points than voxels along the box's longest axis: the
   object fills the window) keeps its whole ridge above τ.
   **A starved surface** (``starved_share``, ``foam_span``): the test assumes a surface is a
   small part of its window. Real echoes add less coherently than simulated ones, so a real image
   is a thick, blurred shell whose voxels barely stand above the window's mean (the real AirSAS
   bunny: median ratio 1.10 among the voxels at or above half of τ), and the test keeps a few
   per cent of its ridge, scattered specks of the object. A sparse survey's sidelobe streaks give
   the same small share, but there the ridge without the test is a foam spread through the box.
   So when the test keeps less than ``starved_share`` of the ridge at or above τ, that ridge is
   kept instead if its points span less than ``foam_span`` of the box's volume
   (:func:`span_share`): measured 0.23 on the real bunny against 0.80-0.87 on the nine sparse
   scenes' backprojections, the 5 kHz band's and the tall box's (docs/decisions/starved-surface.md).
   **The edge of the estimate** (``support_margin``): a neural field is evaluated inside its
   occupancy mask only and is exactly zero elsewhere. Within a range resolution or so of the
   mask's edge the smoothed magnitude and the local mean both see that cut-off rather than the
   data, and on sparse surveys the fit leaves faint sheets there that pass the test (the neural
   meshes were foams at twice the true area). Ridge candidates must lie ``support_margin`` range
   resolutions inside the voxels of non-zero magnitude; a backprojection image, non-zero
   everywhere, is untouched (docs/decisions/estimate-edge-margin.md).
   **Bright pieces** (``piece_level``, ``piece_reach``): what passes the contrast test apart
   from the object, such as the grating lobes of a coarse angular sampling that a box wider
   than the object keeps (their streaks lie 5-10 cm off it), is dimmer than the object: each
   26-connected piece of ridge must hold a point at or above Otsu's level of the ridge's own
   magnitudes (the split between its bright and its dim points), or come within
   ``piece_reach`` range resolutions of a piece that does (a dim continuation of the object
   across a gap in the ridge, like a sphere's underside lit only at grazing angles)
   (docs/decisions/bright-pieces.md).
   **Specks** (``min_piece``): a piece with fewer points than ``min_piece`` of the largest
   piece's is an isolated noise peak, and goes, unless it lies within the same ``piece_reach``
   of a larger piece: a surface lit at grazing angles (the lower flank of an object on the floor)
   breaks into small ridge pieces along the sheet they continue (docs/decisions/specks-by-the-sheet.md).
   **Fog** (``fog_share``; off by default): a candidate for a neural field's volume, measured
   and not adopted (docs/results.md, "A fog step for the neural ridge", with the old
   background). On sparse surveys the fit leaves faint sheets in empty space that passed the
   contrast test; when more than ``fog_share`` of the ridge lies below τ, the points below τ
   go, and each remaining piece must hold a point at or above Otsu's level of the ridge's own
   magnitudes.
3. **Ridge:** non-maximum suppression across the shell (:mod:`shsas_core.evaluation.ridge`): one sheet of
   sub-voxel points where the magnitude peaks, instead of the shell's full thickness, in the
   magnitude smoothed over ``smoothing`` range resolutions (the scales of steps 3-5 are shares of
   the survey's range resolution ``c / 2B``, the width of an echo's mainlobe, not of the voxel:
   a finer grid over the same image finds the same surface).
4. **Normals** across the sheet of the magnitude smoothed by ``normal_smoothing`` (coarser than
   the ridge's own ``smoothing``: speckle turns the fine sheet's direction along the surface),
   each turned toward the sensors that lit its point (``sensors``, the survey's transmitter
   positions): those whose line of sight to it the object, the image's voxels at or above τ,
   leaves open (:func:`~shsas_core.evaluation.ridge.visibility_votes`).
5. **Mesh:** screened Poisson through the oriented points, minus the range sidelobes of brighter
   points (a weaker point standing in front of a brighter one's sheet, within ``sidelobe_reach``
   range resolutions along its normal; the cloud keeps them), on an octree no finer than
   ``poisson_cell`` range resolutions, trimmed to ``trim`` range resolutions from the points
   and to ``sheet_trim`` off their sheet (Poisson's own closure, a lid over a bowl's mouth or a
   bend past the data's edge, leaves the sheet of the nearest points; a bridge across a gap in
   the sheet does not: docs/decisions/sheet-trim.md), simplified
   (:mod:`shsas_core.evaluation.meshing`).

``surface = "threshold"`` keeps every voxel centre at or above τ (no ridge, no contrast test) and
``mesher = "marching_cubes"`` meshes the normalised magnitude's iso-surface at τ: together they
are the paper's extraction (``--preset paper``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import ShsasError
from shsas_core.data.volume import Grid, Volume
from shsas_core.spec.options import MESHER, MESHER_HELP, SURFACE, SURFACE_HELP, Mesher, Surface

if TYPE_CHECKING:
    from shsas_core.evaluation.ridge import Ridge

#: The paper's fixed iso level on the normalised magnitude (reported beside the rule's τ).
PAPER_TAU = 0.2
#: The contrast test keeps too little of a surface below this share of the image's ridge at or
#: above τ (the same sheet without the test). Measured (benchmarks/bench_variants.py and the
#: fidelity suite's dense and anisotropic fits): 0.52-1.46 on every backprojection and neural
#: volume of the nine scenes and of the demo's survey with long records, another sample rate or
#: 5 dB (the test's candidates start at half of τ, so it can keep more than the ridge at τ); 0.062
#: on the 5 kHz band (c/2B 34 mm) and 0.066 on a box 20 cm taller than the object, whose clouds
#: lost most of the surface (surface F1 0.06 and a 3-piece mesh 20x the demo's Chamfer-L2; Reed's
#: field in that box, an 11-piece foam: 0.083); 0.04-0.13 on backprojections of the nine sparse
#: (360-ping) scenes, whose ridge without the test is sidelobe foam; on the real AirSAS bunny
#: (27,000 pings): backprojection 0.073, Reed 0.387 and SH-SAS 0.535. 0.2 lies between, a factor
#: of 1.9 from the lowest good result. Below it the extraction asks whether the ridge without the
#: test is foam (``foam_span``) and the diagnostics warn (``surface_unclear``).
SURFACE_KEPT_LIMIT = 0.2


class ExtractConfig(BaseModel):
    """How to turn a volume into a point cloud and a mesh (module doc)."""

    model_config = ConfigDict(extra="forbid")

    surface: Surface = Field(SURFACE, description=SURFACE_HELP)
    mesher: Mesher = Field(MESHER, description=MESHER_HELP)

    threshold: float | None = Field(None, gt=0, lt=1, description="normalised iso level τ; None = rule")
    rule: Literal["otsu", "percentile"] = Field("otsu", description="rule for τ when threshold is None")
    percentile: float = Field(99.0, gt=0, lt=100, description="for rule='percentile': keep voxels above it")
    tau_min: float = Field(0.05, gt=0, lt=1, description="lower clip of the rule's τ")
    tau_max: float = Field(0.9, gt=0, lt=1, description="upper clip of the rule's τ")
    candidate_share: float = Field(0.5, gt=0, le=1, description="ridge candidates at or above this "
                                   "share of τ (then the contrast test)")
    close_boundary: bool = Field(True, description="pad with empty voxels so meshes close at the box faces")
    chunk: int = Field(65536, ge=1, description="grid points per field evaluation (memory bound)")
    smoothing: float = Field(0.443, ge=0, le=5, description="Gaussian smoothing before the ridge test, "
                             "in range resolutions c/2B (0.443: the range mainlobe's half width at half maximum)")
    normal_smoothing: float = Field(0.886, ge=0, le=5, description="Gaussian smoothing before the ridge "
                                    "points' normals are taken, in range resolutions (0.886: the "
                                    "mainlobe's full width at half maximum)")
    resolution_voxels: float = Field(3.4, gt=0, description="the range resolution in voxels when the "
                                     "survey's is not given (the default survey's 8.6 mm over the "
                                     "default 2.5 mm voxel)")
    sidelobe_reach: float = Field(1.0, ge=0, le=5, description="Poisson is fed no ridge point standing "
                                  "within this many range resolutions in front of a stronger one's sheet "
                                  "(its range sidelobe); 0: off")
    poisson_cell: float = Field(0.5, ge=0, le=5, description="Poisson's finest cell, in range resolutions "
                                "(never finer than a voxel)")
    background_window: float = Field(0.05, gt=0, description="edge of the cube the local background "
                                     "mean is taken over, m")
    contrast_weak: float = Field(2.5, gt=0, description="ridge voxels kept at this multiple of the local "
                                 "background mean when connected to a strong one")
    contrast_strong: float = Field(3.0, gt=0, description="a ridge piece needs one voxel at this multiple")
    background: Literal["estimated", "all"] = Field("all", description="the voxels the contrast "
                                                    "test's local mean is taken over: 'estimated' leaves "
                                                    "out those of zero magnitude (no estimate: outside a "
                                                    "neural field's occupancy mask), 'all' counts them as "
                                                    "dark background")
    support_margin: float = Field(1.25, ge=0, le=5, description="ridge candidates lie at least this "
                                  "many range resolutions inside the voxels the volume estimates (non-zero "
                                  "magnitude: a neural field's occupancy mask); 0: off")
    piece_level: float | None = Field(1.0, gt=0, le=1, description="each ridge piece holds a point at "
                                      "this share of Otsu's level of the ridge's magnitudes or lies within "
                                      "piece_reach of one that does (module doc, step 2); None: off")
    piece_reach: float = Field(2.0, ge=0, le=10, description="how near a dim (or small) ridge piece must come "
                               "to a bright (or large) one to stay, in range resolutions")
    fog_share: float | None = Field(None, ge=0, le=1, description="the fog step for a neural field's "
                                    "ridge (module doc, step 2): when more than this share of it lies below "
                                    "τ, those points go and each piece must reach Otsu's level of the ridge's "
                                    "magnitudes; None: off")
    starved_share: float | None = Field(SURFACE_KEPT_LIMIT, gt=0, le=1, description="when the contrast "
                                        "test keeps less than this share of the ridge at or above τ and "
                                        "that ridge spans less than foam_span of the box, it keeps the "
                                        "ridge at or above τ instead (module doc, step 2); None: off")
    foam_span: float = Field(0.5, gt=0, le=1, description="a ridge whose points span at least this share "
                             "of the scene box's volume (span_share) is sidelobe foam, not a starved surface")
    min_piece: float = Field(0.01, ge=0, lt=1, description="ridge pieces with fewer points than this share "
                             "of the largest piece's are dropped as specks unless they lie within "
                             "piece_reach of a larger piece (module doc, step 2)")
    trim: float = Field(1.45, gt=0, description="Poisson faces farther than this many range resolutions "
                        "from every surface point are cut")
    sheet_trim: float | None = Field(0.75, gt=0, description="Poisson faces farther than this many range "
                                     "resolutions off the sheet of their nearest surface points (along "
                                     "those points' normals) are cut; None: no such cut "
                                     "(docs/decisions/sheet-trim.md)")
    faces_per_point: float = Field(2.0, gt=0, description="face budget of the simplified mesh per surface point")
    max_faces: int = Field(200_000, ge=100, description="most faces of the simplified mesh")
    mesh_min_piece: float = Field(0.05, ge=0, lt=1, description="mesh pieces with less area than this "
                                  "share of the largest piece's are dropped")


@dataclasses.dataclass
class PointCloud:
    """Points with one scalar each.

    Attributes:
        points: (P, 3) float64 positions, m, survey frame (voxel centres for a threshold cloud,
            sub-voxel ridge points for a ridge cloud).
        scalars: (P,) float32 normalised magnitude at the point's voxel, in [τ, 1] (ridge clouds:
            from ``candidate_share`` x τ).
        normals: (P, 3) float64 unit normals facing the sensors (ridge clouds), or None.
    """

    points: np.ndarray
    scalars: np.ndarray
    normals: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])


def normalize(volume: Volume) -> np.ndarray:
    """``grid.shape`` float32 magnitude scaled to [0, 1] by its range (a constant volume gives 0)."""
    m = volume.magnitude()
    if m.size == 0:
        return m
    lo, hi = float(m.min()), float(m.max())
    if not hi > lo:
        return np.zeros_like(m)
    return ((m - lo) / (hi - lo)).astype(np.float32)


def otsu_threshold(values: np.ndarray, bins: int = 256) -> float:
    """Otsu's threshold of ``values`` (any shape): the level maximising between-class variance."""
    from skimage.filters import threshold_otsu

    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 0 or float(v.max()) == float(v.min()):
        return float(v.max()) if v.size else 0.0
    return float(threshold_otsu(v, nbins=bins))


def choose_threshold(volume: Volume, config: ExtractConfig | None = None) -> float:
    """τ for ``volume``: ``config.threshold`` if given, else the documented rule (module doc)."""
    cfg = config or ExtractConfig()
    if cfg.threshold is not None:
        return float(cfg.threshold)
    norm = normalize(volume)
    if cfg.rule == "otsu":
        tau = otsu_threshold(norm)
    else:
        tau = float(np.percentile(norm, cfg.percentile))
    return float(np.clip(tau, cfg.tau_min, cfg.tau_max))


def point_cloud(volume: Volume, tau: float) -> PointCloud:
    """Voxel centres whose normalised magnitude is >= ``tau``.

    Returns:
        PointCloud with (P, 3) survey-frame centres, m, and their normalised magnitudes.
    """
    _check_tau(tau)
    norm = normalize(volume)
    idx = np.argwhere(norm >= tau)
    lo, d = np.asarray(volume.grid.box_min), volume.grid.spacing
    pts = lo + (idx + 0.5) * d
    return PointCloud(pts.astype(np.float64), norm[tuple(idx.T)].astype(np.float32))


def mesh(volume: Volume, tau: float, close_boundary: bool = True):
    """Marching-cubes iso-surface of the normalised magnitude at ``tau``.

    Vertices are in survey-frame metres: skimage returns positions in units of ``spacing``
    measured from the centre of voxel (0, 0, 0), which sits at ``box_min + spacing/2`` (one voxel
    further out when the volume is padded to close the surface at the box faces).

    Returns:
        ``trimesh.Trimesh`` (empty when no voxel reaches ``tau``).
    """
    import trimesh
    from skimage.measure import marching_cubes

    _check_tau(tau)
    norm = normalize(volume)
    if norm.size == 0 or float(norm.max()) < tau or (min(norm.shape) < 2 and not close_boundary):
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    pad = 1 if close_boundary else 0
    if pad:
        norm = np.pad(norm, 1, mode="constant", constant_values=0.0)
    if float(norm.min()) > tau:  # whole box above τ and no padding: no crossing
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    d = volume.grid.spacing
    verts, faces, _normals, _ = marching_cubes(norm, level=tau, spacing=tuple(float(s) for s in d),
                                              allow_degenerate=False)
    origin = np.asarray(volume.grid.box_min) + (0.5 - pad) * d
    verts = verts.astype(np.float64) + origin
    # skimage's gradient direction makes faces wind inward for "bright inside" volumes; flip so
    # normals point out of the object (away from high magnitude), as viewers expect.
    faces = faces[:, ::-1].astype(np.int64)
    return trimesh.Trimesh(verts, faces, process=False)


def local_contrast(norm: np.ndarray, spacing: np.ndarray, window: float,
                   support: np.ndarray | None = None) -> np.ndarray:
    """``norm`` over its mean in a cube of edge ``window`` m around each voxel (module doc, step 2).

    Args:
        norm: (X, Y, Z) normalised magnitude; spacing: (3,) voxel size, m.
        support: (X, Y, Z) bool, the voxels the volume holds an estimate for; the mean is taken
            over those alone (None: every voxel).
    Returns:
        (X, Y, Z) float32 ratio (0 where the local mean is 0 or no estimate lies in the cube).
    """
    from scipy import ndimage

    size = [max(3, round(window / float(h)) | 1) for h in spacing]  # odd, at least 3 voxels
    values = norm.astype(np.float64) if support is None else np.where(support, norm, 0.0)
    mean = ndimage.uniform_filter(values, size=size, mode="nearest")
    if support is not None:
        share = ndimage.uniform_filter(support.astype(np.float64), size=size, mode="nearest")
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = np.where(share > 1e-9, mean / share, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(mean > 0, norm / mean, 0.0)
    return ratio.astype(np.float32)


def span_share(points: np.ndarray, grid: Grid) -> float:
    """The share of ``grid``'s box volume that the box of ``points`` (P, 3), m, spans between their
    2nd and 98th percentiles on each axis (a few stray points do not stretch it); 0 when empty."""
    if len(points) == 0:
        return 0.0
    lo, hi = np.percentile(points, [2.0, 98.0], axis=0)
    box = np.asarray(grid.box_max, dtype=np.float64) - np.asarray(grid.box_min, dtype=np.float64)
    return float(np.prod(np.clip(hi - lo, 0.0, None)) / np.prod(box))


def inside_support(support: np.ndarray, spacing: np.ndarray, margin: float) -> np.ndarray:
    """(X, Y, Z) bool: the voxels of ``support`` (X, Y, Z bool) at least ``margin`` m from every
    voxel outside it (all of it when nothing lies outside)."""
    from scipy import ndimage

    if support.all():
        return support.copy()
    return ndimage.distance_transform_edt(support, sampling=np.asarray(spacing, dtype=np.float64)) >= margin


def resolution_m(spacing: float, config: ExtractConfig, resolution: float | None) -> float:
    """The range resolution the extraction's scales are measured in, m: ``resolution`` (the
    survey's ``c / 2B``) when given, else ``config.resolution_voxels`` voxels of ``spacing`` m."""
    if resolution is not None and resolution > 0 and math.isfinite(resolution):
        return float(resolution)
    return config.resolution_voxels * float(spacing)


def ridge_sigma(grid_spacing: np.ndarray, config: ExtractConfig, resolution: float | None) -> float:
    """The ridge's Gaussian smoothing in voxels of the grid's finest ``grid_spacing`` (3,) m:
    ``config.smoothing`` range resolutions (:func:`resolution_m`), a share of the point-spread
    function's width, not of the voxel, so a finer grid over the same image finds the same ridge."""
    spacing = float(np.min(grid_spacing))
    return config.smoothing * (resolution_m(spacing, config, resolution) / spacing)


def without_fog(r: Ridge, norm: np.ndarray, tau: float, fog_share: float) -> Ridge:
    """The ridge ``r`` of the normalised magnitude ``norm`` (X, Y, Z) without a fog's faint ridges
    (module doc, step 2, a candidate): unchanged unless more than ``fog_share`` of its points lie
    below ``tau``; then its points at or above ``tau`` whose 26-connected piece holds one at or
    above Otsu's level of all its points' magnitudes."""
    from shsas_core.evaluation.ridge import connected_to_strong

    if len(r) == 0:
        return r
    mags = norm[tuple(r.index.T)]
    above = mags >= tau
    if np.mean(~above) <= fog_share:
        return r
    return connected_to_strong(r.subset(above), norm.shape, otsu_threshold(mags), values=mags[above])


def ridge_cloud(volume: Volume, tau: float, config: ExtractConfig | None = None,
                sensors: np.ndarray | None = None, resolution: float | None = None) -> PointCloud:
    """The surface points of ``volume`` (module doc, steps 1-4), with oriented normals.

    Args:
        volume: the reconstruction.
        tau: the level τ on the normalised magnitude (candidates from ``candidate_share`` x τ).
        sensors: (M, 3) positions of the sensors (transmitters) that lit the scene, m; None:
            normals face away from the centre of the scene box.
        resolution: the survey's range resolution ``c / 2B``, m (None: ``resolution_voxels``).
    Returns:
        PointCloud of sub-voxel ridge points, their voxels' normalised magnitudes and normals.
    """
    from shsas_core.evaluation.ridge import (
        connected_to_strong,
        drop_small_pieces,
        orient_toward_sensors,
        ridge,
        sheet_normals,
        visibility_votes,
    )

    _check_tau(tau)
    cfg = config or ExtractConfig()
    norm = normalize(volume)
    grid = volume.grid
    res = resolution_m(float(np.min(grid.spacing)), cfg, resolution)
    sigma = ridge_sigma(grid.spacing, cfg, resolution)
    sigma_n = cfg.normal_smoothing * (res / float(np.min(grid.spacing)))
    estimated = volume.magnitude() > 0
    contrast = local_contrast(norm, grid.spacing, cfg.background_window,
                              estimated if cfg.background == "estimated" else None)
    weak = min(cfg.contrast_weak, cfg.contrast_strong)
    lo = np.asarray(grid.box_min)
    candidates = (norm >= cfg.candidate_share * tau) & (contrast >= weak)
    if cfg.support_margin > 0:
        candidates &= inside_support(estimated, grid.spacing, cfg.support_margin * res)
    r = ridge(norm, candidates, lo, grid.spacing, sigma)
    r = dataclasses.replace(r, values=contrast[tuple(r.index.T)])
    r = connected_to_strong(r, grid.shape, cfg.contrast_strong)
    if len(r) < max(grid.shape):
        # too coarse or too sparse an image for the contrast test (the object fills the window):
        # fewer points than voxels along one axis of the box is no surface; keep the ridge above τ
        r = ridge(norm, norm >= tau, lo, grid.spacing, sigma)
    elif cfg.starved_share is not None:
        full = ridge(norm, norm >= tau, lo, grid.spacing, sigma)
        if len(r) < cfg.starved_share * len(full) and span_share(full.points, grid) < cfg.foam_span:
            # the test starved a surface rather than removing foam (module doc, step 2)
            r = full
    if cfg.fog_share is not None:
        r = without_fog(r, norm, tau, cfg.fog_share)
    if cfg.piece_level is not None and len(r):
        mags = norm[tuple(r.index.T)]
        r = connected_to_strong(r, grid.shape, cfg.piece_level * otsu_threshold(mags), values=mags,
                                reach=cfg.piece_reach * res)
    r = drop_small_pieces(r, grid.shape, cfg.min_piece, reach=cfg.piece_reach * res)
    if sigma_n != sigma:
        r = dataclasses.replace(r, normals=sheet_normals(norm, r.index, grid.spacing, sigma_n))
    votes = None
    if sensors is None or len(np.atleast_2d(sensors)) == 0:
        centre = 0.5 * (np.asarray(grid.box_min) + np.asarray(grid.box_max))
        # a point "sensor" far out along each point's own direction from the centre
        sensors = centre + 1e3 * (r.points - centre)
    else:
        # the sensors that lit a point are those whose line of sight to it the object leaves
        # open; the object is where the image is bright (at or above τ)
        votes = visibility_votes(r.points, r.normals, np.asarray(sensors, dtype=np.float64), norm >= tau,
                                 lo, grid.spacing, own_cell=res)
    normals = orient_toward_sensors(r.points, r.normals, np.asarray(sensors, dtype=np.float64), votes=votes)
    return PointCloud(r.points, norm[tuple(r.index.T)].astype(np.float32), normals)


def surface_mesh(cloud: PointCloud, spacing: float, config: ExtractConfig | None = None,
                 resolution: float | None = None):
    """Screened Poisson mesh of a ridge cloud (module doc, step 5).

    Args:
        cloud: a ridge cloud (oriented normals). spacing: the voxel size, m.
        resolution: the survey's range resolution, m (None: ``resolution_voxels`` voxels).
    """
    from shsas_core.evaluation.meshing import poisson_mesh
    from shsas_core.evaluation.ridge import suppress_sidelobes

    cfg = config or ExtractConfig()
    if cloud.normals is None:
        raise ShsasError("extract: a Poisson mesh needs oriented normals (a ridge cloud)")
    res = resolution_m(spacing, cfg, resolution)
    pts, nrm = cloud.points, cloud.normals
    if cfg.sidelobe_reach > 0:
        # the cloud keeps every ridge point (its scores count what it finds); the mesh is one sheet
        keep = suppress_sidelobes(pts, nrm, cloud.scalars, reach=cfg.sidelobe_reach * res, gap=spacing,
                                  width=spacing)
        pts, nrm = pts[keep], nrm[keep]
    # the image resolves no detail finer than about half its range resolution: a finer octree
    # only crumples the surface between the points
    return poisson_mesh(pts, nrm, max(spacing, cfg.poisson_cell * res), trim=cfg.trim * res,
                        faces_per_point=cfg.faces_per_point, max_faces=cfg.max_faces,
                        min_piece=cfg.mesh_min_piece,
                        sheet_trim=None if cfg.sheet_trim is None else cfg.sheet_trim * res)


def extract(volume: Volume, config: ExtractConfig | None = None, sensors: np.ndarray | None = None,
            resolution: float | None = None) -> tuple[float, PointCloud, Any]:
    """τ by the config, then the point cloud and the mesh: ``(tau, PointCloud, Trimesh)``.

    Args:
        volume: the reconstruction.
        config: the extraction (module doc).
        sensors: (M, 3) transmitter positions, m, that face the ridge cloud's normals (see
            :func:`ridge_cloud`); unused by a threshold cloud.
        resolution: the survey's range resolution ``c / 2B``, m, that the ridge's smoothing,
            the sidelobe suppression and the mesh's scales are measured in (None:
            ``config.resolution_voxels`` voxels).
    """
    cfg = config or ExtractConfig()
    tau = choose_threshold(volume, cfg)
    spacing = float(np.min(volume.grid.spacing))
    if cfg.surface == "ridge":
        cloud = ridge_cloud(volume, tau, cfg, sensors, resolution)
    else:
        cloud = point_cloud(volume, tau)
    if cfg.mesher == "marching_cubes":
        return tau, cloud, mesh(volume, tau, cfg.close_boundary)
    if cloud.normals is None:
        # a threshold cloud has no sheet to orient: Poisson is fed the ridge of the same volume
        ridge_pts = ridge_cloud(volume, tau, cfg, sensors, resolution)
        return tau, cloud, surface_mesh(ridge_pts, spacing, cfg, resolution)
    return tau, cloud, surface_mesh(cloud, spacing, cfg, resolution)


def threshold_sweep(volume: Volume, taus: Sequence[float],
                    score: Callable[[PointCloud, Any], dict[str, float]] | None = None,
                    close_boundary: bool = True) -> list[dict[str, float]]:
    """Extract at each τ and report sizes (and ``score(point_cloud, mesh)`` when given).

    Returns:
        One dict per τ: ``tau``, ``points``, ``faces`` plus the score's keys.
    """
    rows = []
    for tau in taus:
        pc = point_cloud(volume, float(tau))
        m = mesh(volume, float(tau), close_boundary)
        row = {"tau": float(tau), "points": float(len(pc)), "faces": float(len(m.faces))}
        if score is not None:
            row.update(score(pc, m))
        rows.append(row)
    return rows


def _check_tau(tau: float) -> None:
    if not (0.0 < float(tau) < 1.0) or not math.isfinite(float(tau)):
        raise ShsasError(f"threshold: τ must lie in (0, 1) on the normalised magnitude, got {tau}")
