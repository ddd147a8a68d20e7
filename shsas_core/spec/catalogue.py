"""The reconstruction methods a job can run, in one registry.

The spec's ``methods`` names, the share of the job's progress each takes, whether it is a neural
field and its SH degree were kept in four string tables (spec, pipeline weights, the pipeline's
degree map, the service's quota list); each is now read from :data:`REGISTRY`. A test checks the
spec's ``Method`` literal names exactly these.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class MethodKind:
    """One reconstruction method.

    Attributes:
        name: the spec's name for it.
        cost: its share of a job's time relative to the others (weights the progress fraction).
        neural: a neural field fitted by :mod:`shsas_core.neural.train` (else the backprojection image).
        fixed_degree: SH degree of a neural method that has one (reed: 0); None: the spec's
            ``sh_degree`` (shsas), or no field at all (backprojection).
    """

    name: str
    cost: float
    neural: bool
    fixed_degree: int | None = None

    def sh_degree(self, spec_degree: int) -> int | None:
        """The SH degree the method's field has (None: no field)."""
        if not self.neural:
            return None
        return self.fixed_degree if self.fixed_degree is not None else spec_degree


#: Every method, in the order a default job runs them.
REGISTRY: dict[str, MethodKind] = {m.name: m for m in (
    MethodKind("backprojection", cost=0.15, neural=False),
    MethodKind("reed", cost=1.0, neural=True, fixed_degree=0),  # Reed et al.: isotropic
    MethodKind("shsas", cost=1.0, neural=True),
)}
#: The neural methods (those the training quotas and the memory estimate count).
NEURAL: tuple[str, ...] = tuple(n for n, m in REGISTRY.items() if m.neural)
