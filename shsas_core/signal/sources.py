"""Which signals a stage works on: one rule, :func:`signals_for`.

Every stage that images or fits a survey asks for its signals here (the reconstruction job and
``shsas fit`` through the job's spec, ``shsas backproject``, autofocus), naming a *source*:

=============  ==========================================================================
source         signals (N, T) complex64 on the survey's time axis
=============  ==========================================================================
``auto``       the survey's stored ``extras/deconvolved`` when present (with the survey's
               shape), else ``deconvolve``
``stored``     the stored ``extras/deconvolved``; an error when the survey has none
``deconvolve`` the pulse deconvolution ``config`` asks for, computed now (default Wiener; a
               ``meta.pulse_deconvolved`` survey, or ``method="none"``, gives its analytic
               samples: :func:`~shsas_core.signal.deconv.deconvolve`)
``matched``    the matched filter (correlation with the pulse replica)
``raw``        the analytic signal of the samples
=============  ==========================================================================

The reconstruction job (and so ``shsas fit``) uses ``deconvolve`` with :func:`deconv_config`
of its spec: a job's result depends on its spec and samples only, never on extras a file may
carry. ``shsas backproject`` uses ``auto`` unless told otherwise; autofocus ``deconvolve``.
:func:`~shsas_core.imaging.backprojection.backproject_survey` given no signals images ``stored``
when there are stored signals, else ``matched`` (the imaging library runs no deconvolution of
its own accord).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import ProgressFn, StopFn, no_progress
from shsas_core.data.survey import Survey

if TYPE_CHECKING:
    from shsas_core.signal.deconv import DeconvConfig
    from shsas_core.spec.job import ReconstructionSpec

#: The sources :func:`signals_for` knows (see the module's table).
SignalSource = Literal["auto", "stored", "deconvolve", "matched", "raw"]
#: Where a survey keeps signals deconvolved before it was written (``extras/deconvolved``).
STORED = "deconvolved"


@dataclasses.dataclass(frozen=True)
class Signals:
    """Signals and where they came from.

    Attributes:
        values: (N, T) complex, on the survey's time axis (stored signals as complex64; the
            others as their function gives them).
        label: what they are, for logs and records ("wiener deconvolution", "stored
            extras/deconvolved", "matched filter", "raw (analytic)").
    """

    values: np.ndarray
    label: str


def signals_for(survey: Survey, source: SignalSource = "auto", config: DeconvConfig | None = None, *,
                device: Any = "cpu", progress: ProgressFn = no_progress,
                should_stop: StopFn | None = None) -> Signals:
    """The survey's signals from ``source`` (the module's table gives the precedence of ``auto``).

    Args:
        survey: with its samples loaded (``stored`` and ``auto`` also read its extras).
        source: one of :data:`SignalSource`.
        config: the deconvolution of ``deconvolve`` (and of ``auto`` without stored signals);
            None: Wiener with its defaults.
        device, progress, should_stop: passed to the deconvolution.
    Raises:
        ShsasError: ``stored`` without stored signals; an unknown source.
    """
    from shsas_core.signal.chain import analytic_samples, matched_filter

    if source in ("auto", "stored"):
        if has_stored(survey):
            return Signals(np.asarray(survey.extras[STORED]).astype(np.complex64), f"stored extras/{STORED}")
        if source == "stored":
            raise ShsasError(f"signals: the survey has no extras/{STORED} of its shape {survey.shape} "
                             "(fix: deconvolve them now instead)")
        source = "deconvolve"
    if source == "deconvolve":
        from shsas_core.signal.deconv import DeconvConfig, deconvolve

        cfg = config or DeconvConfig()
        values = deconvolve(survey, cfg, device=device, progress=progress, should_stop=should_stop)
        return Signals(values, f"{cfg.method} deconvolution")
    if source == "matched":
        return Signals(matched_filter(survey), "matched filter")
    if source == "raw":
        return Signals(analytic_samples(survey), "raw (analytic)")
    raise ShsasError(f"signals: unknown source {source!r} (known: auto, stored, deconvolve, matched, raw)")


def has_stored(survey: Survey) -> bool:
    """Whether the survey carries stored deconvolved signals of its own shape."""
    stored = survey.extras.get(STORED)
    return stored is not None and stored.shape == survey.shape


def deconv_config(spec: ReconstructionSpec) -> DeconvConfig:
    """The deconvolution a job runs (``spec.deconvolution``, seeded by ``spec.seed``); its kernel is
    also the neural forward model's point-spread function."""
    from shsas_core.signal.deconv import DeconvConfig

    cfg = DeconvConfig(method=spec.deconvolution)
    if spec.deconvolution == "neural":
        cfg = cfg.model_copy(update={"neural": cfg.neural.model_copy(update={"seed": spec.seed})})
    return cfg
