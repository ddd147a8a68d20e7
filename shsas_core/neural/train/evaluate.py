"""The whole-ping evaluator: a low-noise version of the training data term."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from shsas_core.common.errors import ShsasError
from shsas_core.neural.render.renderer import RenderConfig, render_transients
from shsas_core.neural.train.data import bin_weights, window_mask
from shsas_core.spec.options import NUM_RAYS, SEED, TARGET, UNIFORM_FRACTION, Target


def evaluate_data_loss(field: torch.nn.Module, survey, signals: np.ndarray, ping_indices: Sequence[int],
                       target: Target = TARGET, num_rays: int = NUM_RAYS,
                       amplitude: float | None = None, uniform_fraction: float = UNIFORM_FRACTION,
                       seed: int = SEED) -> float:
    """Relative data residual of whole pings, a low-noise version of the training data term.

    ``Σ p_nk |A ŝ_nk - s_nk|² / Σ p_nk |s_nk|²`` over every valid bin ``k`` of the given pings,
    with ``p`` the trainer's bin-sampling weights (``(1-u)|s|/Σ|s| + u/n_valid`` per ping), ``ŝ``
    rendered by :func:`~shsas_core.neural.render.render_transients` with ``num_rays`` rays, and ``s``
    the signals (``|s|`` for ``target="envelope"``). 0 is a perfect fit; predicting zeros scores 1.

    Args:
        field: trained (or freshly initialised) field. survey, signals: as for :func:`~shsas_core.neural.train.fit`.
        ping_indices: which pings. target: as ``TrainConfig.target``. num_rays: rays per ping.
        amplitude: the scale A (``FitResult.amplitude``); None: the least-squares best A >= 0 for
            these pings, which makes the value independent of the field's overall scale (use it
            to compare an untrained field with a trained one fairly).
        uniform_fraction: ``u`` of the weights. seed: ray jitter seed.
    """
    pings = np.asarray(ping_indices, dtype=np.int64)
    s = np.asarray(signals)[pings]
    s = np.abs(s).astype(np.float64) if target == "envelope" else s.astype(np.complex128)
    p = bin_weights(np.abs(s), window_mask(survey, pings), uniform_fraction)
    den = float((p * np.abs(s) ** 2).sum())
    if not den > 0:
        raise ShsasError("evaluate_data_loss: the signals are all zero inside the scene's range window")
    pred = render_transients(field, survey, pings, RenderConfig(num_rays=num_rays), seed=seed).astype(np.complex128)
    if amplitude is None:
        e_pred = float((p * np.abs(pred) ** 2).sum())
        amplitude = max(float((p * (np.conj(pred) * s)).sum().real) / e_pred, 0.0) if e_pred > 0 else 0.0
    return float((p * np.abs(amplitude * pred - s) ** 2).sum()) / den

