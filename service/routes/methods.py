"""The method catalogue (``GET /methods``): what a spec's ``methods`` may name, with each method's
label and the colour the console draws it in. Read from the torch-free catalogue
(:mod:`shsas_core.spec.catalogue`), so an installed method appears here too."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field

from shsas_core.spec.catalogue import REGISTRY

router = APIRouter()


class MethodOut(BaseModel):
    name: str = Field(description="the spec's name for it")
    label: str = Field(description="its name in tables and figures")
    colour: str = Field(description="its colour in the console's viewer, #rrggbb")
    neural: bool = Field(description="a neural field (counts against the training quotas)")
    default: bool = Field(description="run by a spec that names no methods")


@router.get("/methods", response_model=list[MethodOut])
def methods() -> list[MethodOut]:
    """Every method a spec may name, in the order a job runs them."""
    return [MethodOut(name=m.name, label=m.label, colour=m.colour, neural=m.neural, default=m.default)
            for m in REGISTRY.values()]
