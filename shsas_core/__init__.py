"""shsas_core: the science library of shsas (no web or queue imports here).

Flow (see docs/architecture.md): survey -> io -> signal -> deconv -> backprojection | fields+render+train
-> extract -> export -> metrics -> report, orchestrated by :mod:`shsas_core.pipeline.job`.
"""

__version__ = "0.1.0"
