"""What the renderer, the trainer and the extraction need of a neural scattering field.

:class:`ScatteringField` is that interface: ``forward`` (density, scattering, normals and the
gradient they come from), the field's ``config``, the ``device`` and ``dtype`` its parameters
live on, ``coefficients`` (the angular prior, extraction), ``set_active_degree`` (progressive SH
training) and ``set_active_levels`` (coarse-to-fine hash levels). :class:`~shsas_core.neural.fields.SHField` and
:class:`~shsas_core.neural.fields.occupancy.MaskedField` implement it, so train no longer reaches into
the field's layers or hangs private attributes on it.

:func:`device_dtype` is the one place a module's device and dtype are read; it also serves test
fields and benchmark stand-ins that are plain ``torch.nn.Module`` objects.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import torch

if TYPE_CHECKING:
    from shsas_core.neural.fields.config import FieldConfig


@runtime_checkable
class ScatteringField(Protocol):
    """A neural scattering field as render, train and extract use it."""

    @property
    def config(self) -> FieldConfig: ...

    @property
    def device(self) -> torch.device: ...

    @property
    def dtype(self) -> torch.dtype: ...

    def set_active_degree(self, degree: int | None) -> None:
        """Zero the SH coefficients above ``degree`` in every output (None: all active)."""

    def set_active_levels(self, levels: float | None) -> None:
        """Weight the hash levels for ``levels`` active ones, coarse first (None: all active)."""

    def forward(self, x: torch.Tensor, dirs: torch.Tensor, with_normals: bool = True,
                create_graph: bool | None = None) -> dict[str, torch.Tensor]: ...

    def coefficients(self, x: torch.Tensor) -> torch.Tensor:
        """Complex SH coefficients c_lm(x): x (P, 3) m -> (P, (L+1)^2) complex."""


def device_dtype(module: torch.nn.Module) -> tuple[torch.device, torch.dtype]:
    """Device and floating dtype of a module's first parameter (CPU and float32 without one, or
    for an integer parameter)."""
    p = next(iter(module.parameters()), None)
    if p is None:
        return torch.device("cpu"), torch.float32
    return p.device, (p.dtype if p.is_floating_point() else torch.float32)
