"""Which signals a stage works on.

:func:`deconv_config` is the pulse deconvolution a job's spec asks for (its kernel is also the
neural forward model's point-spread function).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from shsas_core.signal.deconv import DeconvConfig
    from shsas_core.spec.job import ReconstructionSpec


def deconv_config(spec: ReconstructionSpec) -> DeconvConfig:
    """The deconvolution a job runs (``spec.deconvolution``, seeded by ``spec.seed``); its kernel is
    also the neural forward model's point-spread function."""
    from shsas_core.signal.deconv import DeconvConfig

    cfg = DeconvConfig(method=spec.deconvolution)
    if spec.deconvolution == "neural":
        cfg = cfg.model_copy(update={"neural": cfg.neural.model_copy(update={"seed": spec.seed})})
    return cfg
