"""A job's survey as the console plots it: the summary ``shsas info`` prints, the sensor
positions, a few pings' envelopes and the ground-truth mesh when the survey has one.

Served from ``jobs/<id>/survey/``, which the validation child wrote at upload
(:mod:`service.survey_view`): the API process never opens the stored survey itself, so
serving the view costs one small JSON read whatever the survey's format or size. A job
stored before views were made at upload gets its view made once, by a validation child.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import uuid
from pathlib import Path
from typing import Any

from anyio import to_thread
from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response
from pydantic import BaseModel, Field

from jobs.layout import job_paths, survey_view_dir, validation_slots_dir
from jobs.store import Job

from ..deps import JobDep
from ..file_responses import file_response
from ..models import ErrorOut
from ..survey_view import GROUND_TRUTH_NAME, VIEW_NAME
from ..uploads import UploadError
from ..validation import ValidationsBusy, validation_slot, view_in_child

ERRORS = {401: {"model": ErrorOut}, 404: {"model": ErrorOut}}


class Ping(BaseModel):
    index: int
    t0_s: float = Field(description="time of the first sample after transmit")
    dt_s: float = Field(description="time between two envelope points")
    envelope: list[float] = Field(description="|sample| maxima over equal blocks of the ping")


class SurveyView(BaseModel):
    summary: dict[str, Any] = Field(description="what `shsas info --json` prints for the input")
    tx: list[list[float]] = Field(description="transmitter positions, m (evenly thinned)")
    rx: list[list[float]] = Field(description="receiver positions, m (evenly thinned)")
    pings: list[Ping] = Field(description="three pings, evenly spaced")
    ground_truth_url: str | None = Field(description="GLB of the ground-truth mesh, when the survey has one")
    ground_truth_origin_offset: list[float] | None = None


router = APIRouter(tags=["surveys"])


async def _view(request: Request, job: Job) -> tuple[dict, Path]:
    settings = request.app.state.settings
    in_dir, _ = job_paths(settings, job.id)
    folder = survey_view_dir(settings, job.id)
    kept = folder / VIEW_NAME
    if not kept.is_file():
        in_path = in_dir / job.input_name
        if not in_path.is_file():
            raise HTTPException(404, f"reconstruction {job.id} has no stored survey")
        await _make_view(settings, in_path, folder, job.id)
    view = json.loads(kept.read_text())
    view["ground_truth_url"] = (None if view.get("ground_truth_origin_offset") is None
                                else f"/reconstructions/{job.id}/survey/{GROUND_TRUTH_NAME}")
    return view, folder


async def _make_view(settings, in_path: Path, folder: Path, job_id: str) -> None:
    """The view of a job stored before views were made at upload: made once, in a validation
    child (in a validation slot, under its limits), in a work folder inside the job's own."""
    work = in_path.parent.parent / f"survey-work-{uuid.uuid4().hex[:8]}"
    work.mkdir()
    try:
        async with validation_slot(validation_slots_dir(settings), settings.max_concurrent_validations,
                                   settings.validate_wait_s):
            made = await to_thread.run_sync(lambda: view_in_child(
                in_path, work, settings.validate_memory_bytes, settings.validate_timeout_s,
                max_ground_truth_elements=settings.max_ground_truth_elements))
        with contextlib.suppress(OSError):  # a concurrent request put its view in place first
            made.replace(folder)
    except ValidationsBusy:
        raise HTTPException(503, "survey: every validation slot is busy; try again later",
                            headers={"Retry-After": "10"}) from None
    except UploadError as exc:
        raise HTTPException(409, f"the stored survey of reconstruction {job_id} could not be read: "
                                 f"{exc.message}") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)


@router.get("/reconstructions/{job_id}/survey", response_model=SurveyView, responses={
    **ERRORS, 409: {"model": ErrorOut}, 503: {"model": ErrorOut}})
async def survey_view(job: JobDep, request: Request) -> SurveyView:
    """The job's survey: the `shsas info` summary, sensor positions, a few pings, ground truth."""
    return SurveyView.model_validate((await _view(request, job))[0])


@router.get("/reconstructions/{job_id}/survey/ground_truth.glb", responses={
    **ERRORS, 200: {"content": {"model/gltf-binary": {}}}, 206: {"description": "partial content"},
    304: {"description": "not modified"}, 416: {"description": "range not satisfiable"}})
async def ground_truth(job: JobDep, request: Request) -> Response:
    """The survey's ground-truth mesh as GLB (404 when the survey has none)."""
    view, folder = await _view(request, job)
    if view["ground_truth_url"] is None:
        raise HTTPException(404, f"the survey of reconstruction {job.id} has no ground truth")
    return file_response(folder / GROUND_TRUTH_NAME, request.headers, GROUND_TRUTH_NAME)
