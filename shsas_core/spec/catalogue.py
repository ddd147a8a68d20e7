"""The reconstruction methods a job can run: one catalogue, torch-free.

Everything that names a method reads it from :data:`REGISTRY`: the spec's ``methods`` literal,
the CLI's choices, the API's schema and its ``GET /methods`` (the console's colours), the
benchmarks' labels, the job's progress weights and the memory and quota rules (neural or not).
Each entry names the module that implements it (``implementation``, imported only when the
method runs, see :mod:`shsas_core.methods`), so reading the catalogue never loads torch.

Methods outside this package join through the ``shsas.methods`` entry-point group of any
installed distribution: each entry point names a :class:`MethodKind` object (e.g.
``toy = "my_pkg.toy:KIND"``). The built-in methods come first, in the order a default job runs
them; added ones follow, sorted by name, and run only when a spec names them. The catalogue is
read while this module is first imported, so such a module imports only :class:`MethodKind` from
here at its top and the rest inside its ``reconstruct`` (tests/helpers/toy_method.py is one).
"""

from __future__ import annotations

import dataclasses
import warnings
from importlib.metadata import entry_points

#: The entry-point group through which installed distributions add methods.
ENTRY_POINT_GROUP = "shsas.methods"


@dataclasses.dataclass(frozen=True)
class MethodKind:
    """One reconstruction method.

    Attributes:
        name: the spec's name for it.
        cost: its share of a job's time relative to the others (weights the progress fraction).
        neural: a neural field fitted by :mod:`shsas_core.neural.train` (the training quotas and
            the memory estimate count it).
        implementation: the module whose ``reconstruct(ctx) -> MethodResult`` runs it
            (:mod:`shsas_core.methods`); imported only when the method runs.
        label: its name in tables and figures.
        colour: its colour in the console's viewer, ``#rrggbb``.
        fixed_degree: SH degree of a neural method that has one (reed: 0); None: the spec's
            ``sh_degree`` (shsas), or no field at all (a method that is not neural).
        default: whether a job that names no methods runs it.
    """

    name: str
    cost: float
    neural: bool
    implementation: str
    label: str
    colour: str
    fixed_degree: int | None = None
    default: bool = False

    def sh_degree(self, spec_degree: int) -> int | None:
        """The SH degree the method's field has (None: no field)."""
        if not self.neural:
            return None
        return self.fixed_degree if self.fixed_degree is not None else spec_degree


_BUILT_IN: tuple[MethodKind, ...] = (
    MethodKind("backprojection", cost=0.15, neural=False, implementation="shsas_core.methods.backprojection",
               label="Backprojection", colour="#4f9de0", default=True),
    MethodKind("reed", cost=1.0, neural=True, implementation="shsas_core.methods.reed",  # Reed et al.: isotropic
               label="Reed et al. (L=0)", colour="#e0a34f", fixed_degree=0, default=True),
    MethodKind("shsas", cost=1.0, neural=True, implementation="shsas_core.methods.shsas",
               label="SH-SAS", colour="#6fd08c", default=True),
)


def _installed() -> list[MethodKind]:
    """The methods installed distributions add (a broken entry is warned about and left out)."""
    kinds: list[MethodKind] = []
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        try:
            kind = ep.load()
        except Exception as exc:  # one bad plugin must not take the others down
            warnings.warn(f"method {ep.name!r} ({ep.value}) could not be loaded: {exc}", stacklevel=2)
            continue
        if not isinstance(kind, MethodKind) or kind.name != ep.name:
            warnings.warn(f"method {ep.name!r} ({ep.value}) is not a MethodKind named {ep.name!r}",
                          stacklevel=2)
            continue
        kinds.append(kind)
    return kinds


def _registry() -> dict[str, MethodKind]:
    reg = {m.name: m for m in _BUILT_IN}
    for kind in _installed():
        if kind.name in reg:
            warnings.warn(f"method {kind.name!r} is already defined; the installed one is ignored",
                          stacklevel=2)
            continue
        reg[kind.name] = kind
    return reg


#: Every method: the built-in ones in the order a default job runs them, then the installed ones.
REGISTRY: dict[str, MethodKind] = _registry()
#: The methods' names, in :data:`REGISTRY`'s order.
METHODS: tuple[str, ...] = tuple(REGISTRY)
#: The methods a job that names none runs.
DEFAULT_METHODS: tuple[str, ...] = tuple(n for n, m in REGISTRY.items() if m.default)
#: The neural methods (those the training quotas and the memory estimate count).
NEURAL: tuple[str, ...] = tuple(n for n, m in REGISTRY.items() if m.neural)
#: Method name -> its label in tables and figures.
LABELS: dict[str, str] = {n: m.label for n, m in REGISTRY.items()}
