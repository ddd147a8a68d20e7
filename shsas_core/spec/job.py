"""The job specification shared by the CLI, the HTTP API and the worker.

A reconstruction is fully described by its spec plus its input survey. Components own their
own config models (``DeconvConfig``, ``BackprojectionConfig``, ``FieldConfig``, ``TrainConfig``,
``ExtractConfig``); this module holds the user-facing top-level spec with validated limits.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator
from pydantic.json_schema import DEFAULT_REF_TEMPLATE

from shsas_core.data.survey import SceneBox
from shsas_core.data.volume import auto_grid_count
from shsas_core.spec.catalogue import DEFAULT_METHODS, METHODS, REGISTRY
from shsas_core.spec.options import (
    ANGULAR_PRIOR,
    ANGULAR_PRIOR_HELP,
    AVERAGE_LAST,
    AVERAGE_LAST_HELP,
    COARSE_TO_FINE,
    COARSE_TO_FINE_HELP,
    DEVICE,
    ITERS,
    LR,
    LR_FINAL_HELP,
    MESHER,
    MESHER_HELP,
    NORMAL_WINDOW_HELP,
    NUM_BINS,
    NUM_RAYS,
    PINGS_PER_BATCH,
    SEED,
    SH_DEGREE,
    SURFACE,
    SURFACE_HELP,
    TARGET,
    TARGET_HELP,
    TV_DENSITY_HELP,
    TV_PHASE_HELP,
    TV_SCATTER_HELP,
    AngularPrior,
    AverageLast,
    CoarseToFine,
    DeviceName,
    EncodingName,
    FinalLearningRate,
    GridCount,
    Iters,
    LearningRate,
    Mesher,
    NormalWindow,
    NumBins,
    NumRays,
    PingsPerBatch,
    Seed,
    SHDegree,
    SparsityWeight,
    Surface,
    Target,
    TVWeight,
)

#: The spec fields that only change extraction: a finished job re-extracts from its saved volumes
#: when they change (shsas_core.pipeline.job_cache) instead of reconstructing again.
EXTRACTION_FIELDS: tuple[str, ...] = ("threshold", "surface", "mesher")
#: The names of the method catalogue (shsas_core.spec.catalogue), as a literal so the API's schema
#: lists them; an installed method (entry-point group ``shsas.methods``) joins it.
Method = Literal[METHODS]  # type: ignore[valid-type]
_METHODS_HELP = "methods to run, in order (the method catalogue, shsas_core.spec.catalogue): " + "; ".join(
    f"{m.name}: {m.label}" for m in REGISTRY.values())


class ReconstructionSpec(BaseModel):
    """What to run on a survey. Defaults run on a 2-core CPU in minutes."""

    model_config = ConfigDict(extra="forbid")

    methods: list[Method] = Field(default_factory=lambda: list(DEFAULT_METHODS),
                                  min_length=1, max_length=len(METHODS), description=_METHODS_HELP)
    # the options the components share take their bounds and defaults from shsas_core.spec.options
    sh_degree: SHDegree = Field(SH_DEGREE, description="SH degree L for method 'shsas' (reed is L=0)")
    iters: Iters = ITERS
    grid: GridCount | None = Field(
        None, description="voxels along the longest scene-box axis; None: the count that "
        "makes voxels at most 2.5 mm (half the 5 mm metric voxel, so extraction does not cap the "
        "metric), see shsas_core.data.volume.auto_grid_count")
    device: DeviceName = DEVICE
    seed: Seed = SEED
    deconvolution: Literal["wiener", "neural", "none"] = Field(
        "wiener", description="pulse deconvolution before every method (its kernel is also the psf "
        "forward model's)")
    threshold: float | None = Field(None, gt=0, lt=1, description="normalised iso level; None = documented rule")
    surface: Surface = Field(SURFACE, description=SURFACE_HELP)
    mesher: Mesher = Field(MESHER, description=MESHER_HELP)
    num_bins: NumBins = NUM_BINS
    num_rays: NumRays = NUM_RAYS
    pings_per_batch: PingsPerBatch = PINGS_PER_BATCH
    holdout_fraction: float = Field(0.0, ge=0, lt=0.9, description="pings held out for novel-view errors")
    lr: LearningRate = Field(LR, description="Adam learning rate of the neural methods")
    forward: Literal["psf", "impulse"] = Field(
        "psf", description="forward model of the neural methods: psf convolves the rendered impulse "
        "response with the deconvolution's own point-spread kernel before the data term (a thin "
        "surface then explains a PSF-wide echo); impulse compares it directly, as the paper does "
        "(ideal deconvolution)")
    init: Literal["backprojection", "none"] = Field(
        "backprojection", description="start of the neural methods: backprojection distils the "
        "backprojection image into the field before the time-of-flight fit (shsas_core.neural.warmstart; "
        "converges at CPU budgets); none starts from the near-empty field of the paper")
    occupancy: float | None = Field(
        0.05, ge=0, lt=1, description="occupancy grid of the neural methods: the field is evaluated "
        "(and can be non-zero) only where the backprojection image's normalised magnitude exceeds "
        "this level (and occupancy_floor times the median), dilated by 2 voxels (shsas_core.neural.fields.occupancy; about 3x faster iterations); "
        "None: everywhere in the scene box, as in the paper")
    occupancy_floor: float = Field(
        2.0, ge=0, le=100, description="an occupied voxel must also exceed this multiple of the "
        "image's median magnitude, its blur and clutter floor: on a real image that floor can lie "
        "above the occupancy level, which alone would then mark the whole box "
        "(docs/decisions/occupancy-floor.md); 0: the level alone")
    sparsity: SparsityWeight = Field(
        1.0, description="weight λ2 of the L1 sparsity prior on the neural field's "
        "density (the paper's L_sparse): it removes the low background the data term leaves in "
        "empty space, which otherwise lowers the extraction level (docs/neural.md); 0: off, as in "
        "the paper's simulated setting")
    angular_prior: AngularPrior = Field(ANGULAR_PRIOR, description=ANGULAR_PRIOR_HELP)
    tv_density: TVWeight = Field(0.0, description=TV_DENSITY_HELP)
    tv_scatter: TVWeight = Field(0.0, description=TV_SCATTER_HELP)
    tv_phase: TVWeight = Field(0.0, description=TV_PHASE_HELP)
    normal_window: NormalWindow | None = Field(None, description=NORMAL_WINDOW_HELP)
    lr_final: FinalLearningRate | None = Field(None, description=LR_FINAL_HELP)
    average_last: AverageLast | None = Field(AVERAGE_LAST, description=AVERAGE_LAST_HELP)
    coarse_to_fine: CoarseToFine | None = Field(COARSE_TO_FINE, description=COARSE_TO_FINE_HELP)
    target: Target = Field(TARGET, description=TARGET_HELP)
    encoding: EncodingName = Field(
        "cpu", description="hash-encoding preset of the neural field: cpu (12 levels, 2^17 rows), "
        "small (8 levels, 2^13 rows, finest 128: fastest, for short CPU runs), paper_gpu (the paper's)")

    def grid_count(self, box: SceneBox) -> int:
        """Voxels along the longest axis of ``box`` (``grid``, or the 2.5 mm rule when None)."""
        return self.grid if self.grid is not None else auto_grid_count(box)

    @field_validator("methods")
    @classmethod
    def _unique(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError(f"methods must not repeat: {v}")
        return v


def spec_json_schema(ref_template: str = DEFAULT_REF_TEMPLATE) -> dict[str, Any]:
    """:class:`ReconstructionSpec`'s JSON schema with every property's default filled in (pydantic
    leaves out the defaults of factory-made fields such as ``methods``): the one the HTTP API
    publishes and the console builds its form from, and the one the CLI builds its options from.

    Args:
        ref_template: how references to nested models are written (the OpenAPI document puts
            them under ``#/components/schemas/``).
    """
    schema = ReconstructionSpec.model_json_schema(ref_template=ref_template)
    for name, value in ReconstructionSpec().model_dump(mode="json").items():
        schema["properties"][name].setdefault("default", value)
    return schema


#: The paper's setting (SH-SAS §5: Adam at lr 1e-3, coherent data term on ideally deconvolved
#: signals, 200 bins x ~4,800 rays per batch, the paper's hash grid, trained from the empty field). One flag away (``--preset paper``):
#: it needs a GPU's iteration budget (the paper trains ~50k iterations on simulated scenes).
PAPER_SETTINGS: dict[str, object] = {
    "init": "none", "forward": "impulse", "target": "coherent", "lr": 1e-3, "encoding": "paper_gpu",
    "num_bins": 200, "num_rays": 4800, "iters": 50_000, "occupancy": None, "sparsity": 0.0,
    "angular_prior": 0.0, "normal_window": 1,
    "average_last": None, "coarse_to_fine": None, "surface": "threshold", "mesher": "marching_cubes",
}
PRESETS: dict[str, dict[str, object]] = {"default": {}, "paper": PAPER_SETTINGS}
