"""Artifact routes: list a job's output files and download one (Range, ETag)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, HTTPException, Request
from fastapi.responses import Response

from jobs.layout import job_paths

from ..deps import ERRORS, JobDep, SettingsDep
from ..file_responses import etag_of, file_response, media_type, safe_artifact_path
from ..job_names import content_disposition, download_name
from ..models import Artifact, ArtifactList

router = APIRouter()


@router.get("/reconstructions/{job_id}/artifacts", response_model=ArtifactList, responses=ERRORS)
def list_artifacts(job: JobDep, settings: SettingsDep) -> ArtifactList:
    """The job's output files (empty until it succeeds)."""
    _, out_dir = job_paths(settings, job.id)
    items = []
    for name in job.artifacts:
        p = safe_artifact_path(out_dir, name, job.artifacts)
        if p is not None:
            items.append(Artifact(name=name, url=f"/reconstructions/{job.id}/artifacts/{name}",
                                  size=p.stat().st_size, media_type=media_type(name), etag=etag_of(p)))
    return ArtifactList(job_id=job.id, status=job.status, items=items)  # type: ignore[arg-type]


@router.get("/reconstructions/{job_id}/artifacts/{name}", responses={
    **ERRORS, 206: {"description": "partial content"}, 304: {"description": "not modified"},
    416: {"description": "range not satisfiable"},
    200: {"content": {"application/octet-stream": {}, "model/gltf-binary": {}, "application/json": {},
                      "text/html": {}}}})
def get_artifact(
    job: JobDep, name: str, settings: SettingsDep, request: Request,
    # Declared so that the OpenAPI schema documents them (and fuzzers send them); the
    # values are read from request.headers by file_response.
    range_: Annotated[str | None, Header(alias="Range", description="one byte range: bytes=a-b, bytes=a- or "
                                                     "bytes=-n (206; 416 when unsatisfiable)")] = None,
    if_range: Annotated[str | None, Header(description="an ETag: Range applies only if it matches")] = None,
    if_none_match: Annotated[str | None, Header(description="ETags: 304 if one matches")] = None,
) -> Response:
    """Download one artifact; supports Range and ETag/If-None-Match."""
    _, out_dir = job_paths(settings, job.id)
    p = safe_artifact_path(out_dir, name, job.artifacts)
    if p is None:
        raise HTTPException(404, f"no artifact {name!r} in reconstruction {job.id} "
                                 f"(available: {', '.join(job.artifacts) or 'none yet'})")
    resp = file_response(p, request.headers, name, head=request.method == "HEAD")
    # saved under the uploaded survey's name: scan42_shsas_mesh.glb
    resp.headers["Content-Disposition"] = content_disposition(download_name(job.client_name, name))
    return resp


@router.head("/reconstructions/{job_id}/artifacts/{name}", responses={
    **ERRORS, 304: {"description": "not modified"}, 416: {"description": "range not satisfiable"},
    200: {"description": "the headers of the download (Content-Length, ETag, ...), no body"}})
def head_artifact(job: JobDep, name: str, settings: SettingsDep, request: Request,
                  range_: Annotated[str | None, Header(alias="Range")] = None,
                  if_range: Annotated[str | None, Header()] = None,
                  if_none_match: Annotated[str | None, Header()] = None) -> Response:
    """The headers GET would send (size, type, ETag, Content-Range), without the body."""
    return get_artifact(job, name, settings, request)
