"""The reconstruction methods: each one a module whose ``reconstruct(ctx) -> MethodResult`` turns the
job's deconvolved signals into a volume (:mod:`.backprojection`, :mod:`.reed`, :mod:`.shsas`).

Which methods exist, and which module implements each, is the torch-free catalogue
:data:`shsas_core.spec.catalogue.REGISTRY` (methods outside this package join it through the
``shsas.methods`` entry-point group). The pipeline calls :func:`reconstruct` for each method a
job names and does the rest (extraction, export, scoring, the report) the same way for all.
"""

from __future__ import annotations

import importlib

from shsas_core.common.errors import ShsasError
from shsas_core.methods.base import MethodContext, MethodResult, Reconstruct
from shsas_core.spec.catalogue import REGISTRY

__all__ = ["MethodContext", "MethodResult", "Reconstruct", "implementation", "reconstruct"]


def implementation(name: str) -> Reconstruct:
    """The ``reconstruct`` function of method ``name`` (its module imported now)."""
    kind = REGISTRY.get(name)
    if kind is None:
        raise ShsasError(f"method: unknown method {name!r} (known: {', '.join(REGISTRY)})")
    fn = getattr(importlib.import_module(kind.implementation), "reconstruct", None)
    if not callable(fn):
        raise ShsasError(f"method {name!r}: {kind.implementation} has no reconstruct(ctx)")
    return fn


def reconstruct(ctx: MethodContext) -> MethodResult:
    """Run method ``ctx.name`` on the job ``ctx`` describes."""
    return implementation(ctx.name)(ctx)
