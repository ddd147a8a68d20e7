"""The trainer's options: :class:`TrainConfig` and the loss weights :class:`LossWeights`."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

from shsas_core.neural.render.renderer import RenderConfig
from shsas_core.spec.options import (
    AVERAGE_LAST,
    AVERAGE_LAST_HELP,
    COARSE_TO_FINE,
    COARSE_TO_FINE_HELP,
    ITERS,
    LR,
    LR_FINAL_HELP,
    NUM_BINS,
    NUM_RAYS,
    PINGS_PER_BATCH,
    SEED,
    TARGET,
    TARGET_HELP,
    UNIFORM_FRACTION,
    AverageLast,
    CoarseToFine,
    DeviceName,
    FinalLearningRate,
    Iters,
    LearningRate,
    NumBins,
    NumRays,
    PingsPerBatch,
    Seed,
    Target,
    UniformFraction,
)


class LossWeights(BaseModel):
    """λ1..λ6 of the composite loss (see :mod:`shsas_core.neural.train`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    tof: float = Field(1.0, ge=0, description="λ1, ToF data term")
    # a weight like λ3..λ5, unbounded above; the job spec caps it at 100 for users (SparsityWeight)
    # and defaults it to 1 (the paper's simulated setting is this 0)
    sparsity: float = Field(0.0, ge=0, description="λ2, L1 of density")
    tv_density: float = Field(0.0, ge=0, description="λ3, TV of density")
    tv_scatter: float = Field(0.0, ge=0, description="λ4, TV of |σ|")
    tv_phase: float = Field(0.0, ge=0, description="λ5, TV of ∠σ")
    angular: float = Field(0.0, ge=0, description="λ6, angular roughness Σ l(l+1)|c_lm|² of the SH "
                           "coefficients relative to their DC energy (0 for L = 0)")

    @property
    def any_tv(self) -> bool:
        return self.tv_density > 0 or self.tv_scatter > 0 or self.tv_phase > 0

    @property
    def any_sampled(self) -> bool:
        """Whether a term needs the field at the regularisers' random sample points."""
        return self.any_tv or self.angular > 0


#: The sampling options TrainConfig owns and hands to its RenderConfig.
_SAMPLING = frozenset({"num_bins", "num_rays", "uniform_fraction"})


class TrainConfig(BaseModel):
    """Training options. Defaults run on a 2-core CPU; the paper used 200 bins x ~4800 rays."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # the options a job spec also carries: bounds and defaults from shsas_core.spec.options
    iters: Iters = ITERS
    lr: LearningRate = LR
    lr_final: FinalLearningRate | None = Field(None, description=LR_FINAL_HELP)
    num_bins: NumBins = NUM_BINS
    num_rays: NumRays = NUM_RAYS
    pings_per_batch: PingsPerBatch = PINGS_PER_BATCH
    uniform_fraction: UniformFraction = UNIFORM_FRACTION
    target: Target = Field(TARGET, description=TARGET_HELP)
    weights: LossWeights = LossWeights()
    tv_delta: float | None = Field(None, gt=0, description="TV offset length, m; None: box diagonal/128")
    psf_window: int = Field(64, ge=1, le=4096, description="with a point-spread kernel (fit's psf): "
                            "contiguous target bins per ping and iteration (replaces num_bins)")
    seed: Seed = SEED
    average_last: AverageLast | None = Field(AVERAGE_LAST, description=AVERAGE_LAST_HELP)
    coarse_to_fine: CoarseToFine | None = Field(COARSE_TO_FINE, description=COARSE_TO_FINE_HELP)
    checkpoint_every: int = Field(500, ge=1)
    heap_cache: bool = Field(True, description="keep freed CPU buffers in the heap during the loop "
                             "(glibc; no per-iteration page faults, see shsas_core.common.heap)")
    device: DeviceName = "auto"
    render: RenderConfig = Field(default_factory=RenderConfig, description="the renderer's other options; "
                                 "its num_bins, num_rays and uniform_fraction are the fields above")

    @model_validator(mode="after")
    def _one_sampling_setting(self) -> TrainConfig:
        # render_config() takes these from the fields above: a value set in render as well
        # would be dropped without a word, so it is an error instead
        twice = sorted(self.render.model_fields_set & _SAMPLING)
        if twice:
            raise ValueError(f"render.{', render.'.join(twice)}: set these on TrainConfig itself")
        return self

    def render_config(self) -> RenderConfig:
        return self.render.model_copy(update={"num_bins": self.num_bins, "num_rays": self.num_rays,
                                              "uniform_fraction": self.uniform_fraction})

