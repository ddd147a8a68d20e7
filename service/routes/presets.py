"""Named starting points for a spec and what a spec would cost, before anything is uploaded:
``GET /schemas/reconstruction-presets`` and ``POST /estimates``.

The estimate is the cost model's (``shsas_core.spec.cost``: CPU seconds by part, from rates measured
on a 2-core CPU) and the checks a submission would meet (the training-samples cap, the grid
cap, the CPU-time cap), so the console can say "about 9 h on a CPU, over this server's limit"
while the operator is still choosing. The survey's size is unknown until it is uploaded: its
parts (backprojection, signal processing) count only when the caller gives it.
"""

from __future__ import annotations

from typing import Any

import pydantic
from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, Field

from shsas_core.spec.cost import CPU_FIXED_S, cpu_job_seconds
from shsas_core.spec.job import PRESETS, ReconstructionSpec

from ..deps import ERRORS, Owner, SettingsDep
from ..quotas import check_cpu_time, check_spec_cost
from ..submission import spec_error
from ..uploads import UploadError

router = APIRouter()

#: What the console offers, in order: (name, title, what it is for, spec fields it sets).
#: "standard" is the spec's own defaults; "paper" the paper's setting (shsas_core.spec.job).
PRESET_LIST: list[tuple[str, str, str, dict[str, Any]]] = [
    ("quick", "Quick look", "the backprojection image alone: seconds to a few minutes, to check a survey",
     {"methods": ["backprojection"]}),
    ("standard", "Standard", "every method with the defaults measured best on a CPU", dict(PRESETS["default"])),
    ("paper", "Paper", "the paper's setting (empty start, 200 bins x 4,800 rays, 50k iterations): "
     "needs a GPU worker", dict(PRESETS["paper"])),
]


class Preset(BaseModel):
    name: str
    title: str
    description: str
    spec: dict[str, Any] = Field(description="the spec fields the preset sets; the rest keep their defaults")


class EstimateIn(BaseModel):
    spec: dict[str, Any] = Field(default_factory=dict, description="a ReconstructionSpec (as for POST /reconstructions)")
    pings: int | None = Field(None, ge=0, description="the survey's pings, when known")
    samples_per_ping: int | None = Field(None, ge=0, description="the survey's samples per ping, when known")


class Estimate(BaseModel):
    cpu_s: float = Field(description="estimated seconds on a CPU worker (the parts below plus a fixed floor)")
    parts: dict[str, float] = Field(description="training, backprojection, signal processing and fixed seconds")
    words: str = Field(description="the estimate in words")
    survey_known: bool = Field(description="false: the survey-size parts are left out (no pings given)")
    queue: str = Field(description="the queue the job would run on")
    refused: list[str] = Field(description="why a submission of this spec would be refused now; empty when it would not")


@router.get("/schemas/reconstruction-presets", response_model=list[Preset], tags=["specs"])
def presets() -> list[Preset]:
    """The console's presets: quick look, standard, paper (the spec fields each sets)."""
    return [Preset(name=n, title=t, description=d, spec=s) for n, t, d, s in PRESET_LIST]


@router.post("/estimates", response_model=Estimate, responses={**ERRORS, 422: {"description": "the spec is not valid"}})
def estimate(body: EstimateIn, who: Owner, settings: SettingsDep) -> Estimate:
    """What ``spec`` would cost on a CPU worker, and whether a submission would be refused."""
    try:
        spec = ReconstructionSpec.model_validate(body.spec)
    except pydantic.ValidationError as exc:
        raise HTTPException(422, spec_error(exc)) from None
    pings, samples = body.pings or 0, body.samples_per_ping or 0
    est = cpu_job_seconds(spec, pings, samples)
    refused = []
    summary = {"pings": pings, "samples_per_ping": samples} if pings else None
    for check in (lambda: check_spec_cost(spec, settings), lambda: check_cpu_time(spec, settings, summary)):
        try:
            check()
        except UploadError as e:
            refused.append(e.message)
    return Estimate(cpu_s=round(est.total_s, 1), words=est.words(), survey_known=bool(pings),
                    parts={"train_s": est.train_s, "backprojection_s": est.backprojection_s,
                           "signal_s": est.signal_s, "fixed_s": CPU_FIXED_S},
                    queue=settings.queue_for(spec.device), refused=refused)
