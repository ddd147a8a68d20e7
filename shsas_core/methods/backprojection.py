"""Backprojection: the job's (complex) backprojection image of the training pings is the volume."""

from __future__ import annotations

from shsas_core.common.progress import sub_progress
from shsas_core.methods.base import MethodContext, MethodResult


def reconstruct(ctx: MethodContext) -> MethodResult:
    """The job's cached image (:mod:`shsas_core.imaging.backprojection`), shared with the
    neural methods' warm start."""
    return MethodResult(volume=ctx.image(sub_progress(ctx.progress, 0.0, 0.8)))
