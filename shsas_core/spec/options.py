"""The tunable options a job shares between its components, each declared once.

``ReconstructionSpec`` (the job, read by the CLI, the API and the worker), ``TrainConfig``,
``RenderConfig`` and the ``fit`` / ``backproject`` commands used to declare the same option with
their own bounds (200k against 1M iterations, 65,536 against 1M rays, grid 8..512 against 2..1024).
Each now takes its type (bounds and description) and its default from here, so they cannot
disagree. This module imports nothing of the package: every component can use it.

Pydantic forbids a default inside ``Annotated[..., Field(...)]``, so each default is a constant
beside its type: ``iters: Iters = ITERS``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

#: SH degree L of the neural field (0: isotropic, Reed et al.).
SHDegree = Annotated[int, Field(ge=0, le=3, description="SH degree L; 0 = isotropic (Reed et al.)")]
SH_DEGREE = 3

Iters = Annotated[int, Field(ge=1, le=200_000, description="training iterations per neural method")]
ITERS = 2000

LearningRate = Annotated[float, Field(gt=0, le=1.0, description="Adam learning rate")]
LR = 1e-3
FinalLearningRate = Annotated[float, Field(gt=0, le=1.0)]
#: (an optional field's description must sit on the field itself to reach its JSON schema)
LR_FINAL_HELP = ("learning rate at the last iteration, reached by exponential decay from lr "
                 "(None: constant lr, the paper's setting)")

NumBins = Annotated[int, Field(ge=1, le=4096, description="range bins rendered per ping per iteration")]
NUM_BINS = 64
NumRays = Annotated[int, Field(ge=1, le=65536, description="TX rays per ping per iteration")]
NUM_RAYS = 1024
PingsPerBatch = Annotated[int, Field(ge=1, le=64, description="pings rendered per training iteration")]
PINGS_PER_BATCH = 1

AverageLast = Annotated[float, Field(gt=0, le=1)]
#: Tail averaging of the neural methods (docs/neural.md, "Averaged weights").
AVERAGE_LAST = 0.5
AVERAGE_LAST_HELP = ("the neural field returned is the uniform average of its weights over this last "
                     "fraction of the training iterations (tail averaging), which removes the "
                     "iterate-to-iterate jitter of one-ping batches; None: the last iterate (the paper)")

#: Samples along each TX ray whose field gradients make the Lambertian term's normal (docs/neural.md,
#: "The Lambertian term and its normal").
NormalWindow = Annotated[int, Field(ge=1, le=64)]
#: The window is a length along the ray, one range resolution c/2B: the whole samples in it,
#: ``fs / B`` (docs/decisions/lambertian-normal-window.md; measured against 1 by the fidelity
#: benchmark, and as a length against a count of samples at 250 kHz); the paper's 1 sample is in
#: ``--preset paper``.
NORMAL_WINDOW_RESOLUTIONS = 1.0
#: ... and never fewer samples than this: a sum over fewer is a short, noisy difference (at a
#: 40 kHz band, 2.5 samples a resolution, 2 samples cost SH-SAS 0.028 of surface F1 against 5).
NORMAL_WINDOW_MIN_SAMPLES = 5
#: The renderer's window where no survey is given: one range resolution of the default survey
#: (100 kHz, 10-30 kHz: 5 samples).
NORMAL_WINDOW = 5
NORMAL_WINDOW_HELP = ("the Lambertian term's normal at a sample is -∇|σ_DC| summed over this many consecutive "
                      "samples along its TX ray, ending at the sample (bins of one range window: under the impulse "
                      "forward model, chosen or on pre-deconvolved pings, the fit uses 1); 1: the sample's own "
                      "gradient (the paper); None: the samples in one range resolution c/2B of the survey "
                      "(fs / B: 5 at 100 kHz and 10-30 kHz, 12 at 250 kHz), at least 5. A thin shell's own gradient "
                      "vanishes at its ridge and points back at the sonar past it, so only the near flank "
                      "is lit and the fit builds a double sheet; a window lights the ridge and gives one "
                      "sheet (docs/neural.md)")

CoarseToFine = Annotated[float, Field(gt=0, le=1)]
#: Coarse-to-fine starts with the hash levels of resolution up to this on (8 of the ``cpu``
#: preset's 12: 16 … 145 cells across the box).
COARSE_TO_FINE_START_RESOLUTION = 150
#: Coarse-to-fine hash levels (docs/neural.md, "Coarse-to-fine hash levels"): the fraction of the
#: training iterations over which the fine levels come in; None: every level from the start.
COARSE_TO_FINE: float | None = 0.25
COARSE_TO_FINE_HELP = ("the neural field's hash levels finer than resolution "
                       f"{COARSE_TO_FINE_START_RESOLUTION} start switched off (the start from "
                       "backprojection is distilled without them) and come in one after the other, each "
                       "through a cosine window, over this fraction of the training iterations; None: "
                       "every level from the start (the paper)")

Seed = Annotated[int, Field(ge=0, le=2**31 - 1, description="seed of every random draw")]
SEED = 0

DeviceName = Annotated[str, Field(pattern=r"^(auto|cpu|cuda(:\d+)?)$",
                                  description="auto (CUDA when present), cpu, cuda or cuda:N")]
DEVICE = "auto"

Target = Literal["coherent", "envelope"]
TARGET: Target = "coherent"
TARGET_HELP = ("data term of the neural methods: coherent fits complex s_PD (the paper); envelope fits "
               "|s_PD| (real, >= 0), which converges at CPU budgets (docs/neural.md)")

#: The hash-encoding presets by name (shsas_core.neural.fields.encoding.PRESETS; a test checks they
#: agree). Here, not read from there, so the CLI can list them without importing torch.
EncodingName = Literal["cpu", "small", "paper_gpu"]

#: Voxels along the longest scene-box axis of a reconstruction grid.
GridCount = Annotated[int, Field(ge=8, le=512, description="voxels along the longest scene-box axis")]

UniformFraction = Annotated[float, Field(ge=0, le=1, description="uniform share of the range-bin sampling pdf")]
UNIFORM_FRACTION = 0.1

#: Weight λ6 of the angular prior on SH-SAS's coefficients (shsas_core.neural.train.relative_angular_roughness).
AngularPrior = Annotated[float, Field(ge=0, le=100.0, description="weight λ6 of the angular prior")]
ANGULAR_PRIOR = 0.0
ANGULAR_PRIOR_HELP = ("weight λ6 of the angular prior on SH-SAS's scattering lobes: their Dirichlet energy "
                      "on the sphere, Σ l(l+1)|c_lm|², over their isotropic energy |c_00|², so a lobe "
                      "turns directional only as far as the echoes demand (docs/neural.md); 0: off, as "
                      "in the paper; no effect at L = 0 (Reed)")

#: Weights λ3..λ5 of the total-variation priors on the field (shsas_core.neural.train.losses): the
#: paper turns them on for its real AirSAS scenes, off for simulated ones.
TVWeight = Annotated[float, Field(ge=0, le=100.0, description="weight of a total-variation prior")]
TV_DENSITY_HELP = ("weight λ3 of the total-variation prior on the neural field's density, "
                   "mean |ρ(x) - ρ(x+δ)| at random valid samples x, |δ| = scene-box diagonal / 128; "
                   "0: off, as in the paper's simulated setting")
TV_SCATTER_HELP = ("weight λ4 of the total-variation prior on the scattering magnitude, "
                   "mean ||σ(x)| - |σ(x+δ)||; 0: off (the paper weighs it on its AirSAS scenes)")
TV_PHASE_HELP = ("weight λ5 of the total-variation prior on the scattering phase, mean "
                 "|e^{i∠σ(x)} - e^{i∠σ(x+δ)}|; 0: off (the paper weighs it on its AirSAS scenes)")

#: Weight λ2 of the L1 sparsity prior on the field's density.
SparsityWeight = Annotated[float, Field(ge=0, le=100.0, description="weight λ2 of the L1 sparsity prior "
                                        "on the neural field's density; 0: off")]

Surface = Literal["ridge", "threshold"]
Mesher = Literal["poisson", "marching_cubes"]
#: The defaults of the two choices, declared once (the spec's and the extraction's fields take them from here).
SURFACE: Surface = "ridge"
MESHER: Mesher = "poisson"
SURFACE_HELP = ("surface points: ridge (the sheet where the magnitude peaks, kept by a local-contrast "
                "test; shsas_core.evaluation.extract) or threshold (every voxel at or above the level, as in the paper)")
MESHER_HELP = ("mesh: poisson (screened Poisson through the oriented surface points, trimmed and "
               "simplified) or marching_cubes (iso-surface of the volume at the level, as in the paper)")
