"""SH-SAS: a neural scattering field with spherical-harmonic scattering of degree ``spec.sh_degree``."""

from __future__ import annotations

from shsas_core.methods.base import MethodContext, MethodResult
from shsas_core.methods.neural import fit_field


def reconstruct(ctx: MethodContext) -> MethodResult:
    """Fit the degree-``spec.sh_degree`` field to the training pings
    (:func:`~shsas_core.methods.neural.fit_field`)."""
    return fit_field(ctx)
