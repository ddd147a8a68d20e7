"""Analysis-by-synthesis training of a scattering field on pulse-deconvolved pings (paper §4.4).

Each iteration picks ``pings_per_batch`` training pings, importance-samples ``num_bins`` range bins
per ping (∝ |s_PD| plus a uniform share), renders them with ``num_rays`` TX rays
(:mod:`shsas_core.neural.render`), and takes one Adam step (lr 1e-3) on the composite loss

    L = λ1 L_ToF + λ2 L_sparse + λ3 TV(ρ) + λ4 TV(|σ|) + λ5 TV(∠σ) + λ6 L_ang

* ``L_ToF = mean_k |A ŝ_k - s_k|^2 / E`` — mean squared complex error (real² + imag²) of the
  rendered bins, divided by the constant ``E``, the expected |s|² of a bin drawn by the sampler
  (averaged over the training pings); predicting zeros scores 1.0 in expectation, so the value
  reads as a relative residual.
* ``L_sparse = mean ρ(x)`` over the valid samples (L1: ρ >= 0).
* TV terms compare the field at ``REGULARISER_POINTS`` (4096) random valid samples ``x`` and at ``x + δ``, ``δ`` a random
  direction of length ``tv_delta`` (default: 1/128 of the scene-box diagonal):
  ``TV(ρ) = mean |ρ(x) - ρ(x+δ)|``, ``TV(|σ|) = mean ||σ(x)| - |σ(x+δ)||``,
  ``TV(∠σ) = mean |e^{i∠σ(x)} - e^{i∠σ(x+δ)}|`` (chord distance on the unit circle: ≈ |Δφ|
  for small differences, no 2π wrap, bounded gradient).
* ``L_ang = Σ_x Σ_lm l(l+1)|c_lm(x)|² / Σ_x |c_00(x)|²`` over the same samples: the
  scattering lobe's Dirichlet energy on the sphere relative to its isotropic energy
  (:func:`relative_angular_roughness`), a prior towards smooth, low-degree lobes (not in the paper).

Data term (``TrainConfig.target``): ``"coherent"`` (default, the paper) fits the complex s_PD;
``"envelope"`` replaces every target ``s_k`` by ``|s_k|`` (real, non-negative) before anything
else, so ``E`` and the bin sampler see ``|s|`` too. Envelope is a deviation from the paper for
CPU budgets: the paper's renderer assumes ideal pulse deconvolution, while Wiener s_PD keeps the
band-pass pulse PSF (carrier under an envelope), which a coherent fit can only explain with a
complex σ oscillating along range (long GPU runs); |s_PD| has no carrier, so a density shell on
the surface explains it within a few hundred iterations (docs/neural.md).

``A = exp(log_amplitude)`` is one learnable real scale, initialised in closed form before the
first step as ``‖s‖ / ‖ŝ‖`` over 8 seeded batches, so the field does not have to grow its output by
orders of magnitude to meet the data's units. Default weights follow the paper's simulated
setting (regularisers off: λ1 = 1, λ2..λ6 = 0); the job spec sets λ2..λ6 (sparsity, the TV
weights, the angular prior).

Determinism and resume: every random draw of iteration ``i`` comes from generators seeded with
``(seed, i)``, so the draws do not depend on history; a checkpoint (field, amplitude, optimiser,
iteration, loss history and the global torch/numpy/python RNG states, written atomically)
therefore resumes to the same loss curve as an uninterrupted run.

The package, one concern a module: :mod:`~.config` (the options), :mod:`~.data` (signals and the
batch sampler), :mod:`~.losses`, :mod:`~.schedules` (lr decay, coarse-to-fine
levels, weight averaging, as callbacks of the loop), :mod:`~.checkpoint`, :mod:`~.loop` (the
:class:`Trainer` and :func:`fit`) and :mod:`~.evaluate` (the whole-ping evaluator).
"""

from shsas_core.neural.train.checkpoint import CHECKPOINT_NAME, load_checkpoint
from shsas_core.neural.train.config import LossWeights, TrainConfig
from shsas_core.neural.train.evaluate import evaluate_data_loss
from shsas_core.neural.train.loop import FitResult, Trainer, fit
from shsas_core.neural.train.losses import convolve_psf, relative_angular_roughness
from shsas_core.neural.train.schedules import active_levels, coarse_start_levels, scheduled_lr
from shsas_core.spec.options import COARSE_TO_FINE_START_RESOLUTION

__all__ = [
    "CHECKPOINT_NAME", "COARSE_TO_FINE_START_RESOLUTION", "FitResult", "LossWeights",
    "TrainConfig", "Trainer", "active_levels", "coarse_start_levels", "convolve_psf", "evaluate_data_loss",
    "fit", "load_checkpoint", "relative_angular_roughness", "scheduled_lr",
]
