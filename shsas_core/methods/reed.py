"""Reed et al.: an isotropic neural scattering field (SH degree 0, the catalogue's fixed degree)."""

from __future__ import annotations

from shsas_core.methods.base import MethodContext, MethodResult
from shsas_core.methods.neural import fit_field


def reconstruct(ctx: MethodContext) -> MethodResult:
    """Fit the degree-0 field to the training pings (:func:`~shsas_core.methods.neural.fit_field`)."""
    return fit_field(ctx)
