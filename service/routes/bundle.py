"""Every file of a finished job in one zip, streamed as it is made (never built in memory or on
disk): ``GET /reconstructions/{id}/artifacts.zip``."""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import StreamingResponse

from jobs.layout import job_paths

from ..deps import ERRORS, JobDep, SettingsDep
from ..file_responses import safe_artifact_path
from ..job_names import content_disposition, download_name

router = APIRouter()

#: Bytes read from a file at a time; also about the most the response holds at once.
CHUNK = 1 << 20


class _Pipe:
    """A write-only file for ``zipfile`` whose bytes are taken out as they come. It has no
    ``tell``/``seek``, so zipfile writes each member's sizes after its data (data descriptors),
    as a stream needs."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []

    def write(self, b: bytes) -> int:
        self.parts.append(bytes(b))
        return len(b)

    def flush(self) -> None:
        pass

    def take(self) -> bytes:
        out, self.parts = b"".join(self.parts), []
        return out


def zip_stream(files: list[tuple[str, Path]]) -> Iterator[bytes]:
    """The zip of ``files`` (name in the archive, path), a chunk at a time. Stored, not deflated:
    the meshes, clouds and volumes hardly compress, and storing costs no CPU."""
    pipe = _Pipe()
    with zipfile.ZipFile(pipe, mode="w", compression=zipfile.ZIP_STORED) as zf:  # type: ignore[arg-type]
        for name, path in files:
            with open(path, "rb") as src, zf.open(name, mode="w", force_zip64=True) as dst:
                while chunk := src.read(CHUNK):
                    dst.write(chunk)
                    yield pipe.take()
            yield pipe.take()
    yield pipe.take()  # the central directory


@router.get("/reconstructions/{job_id}/artifacts.zip", responses={
    **ERRORS, 409: {"description": "the job has no files yet"},
    200: {"content": {"application/zip": {}}, "description": "every artifact, streamed"}})
def download_all(job: JobDep, settings: SettingsDep) -> StreamingResponse:
    """Every artifact of the job in one zip (named after the uploaded survey), streamed."""
    if not job.artifacts:
        raise HTTPException(409, f"reconstruction {job.id} has no files to download (status {job.status})")
    _, out_dir = job_paths(settings, job.id)
    files = [(name, p) for name in job.artifacts if (p := safe_artifact_path(out_dir, name, job.artifacts))]
    name = download_name(job.client_name, "results.zip") if job.client_name else f"{job.id[:8]}_results.zip"
    return StreamingResponse(zip_stream(files), media_type="application/zip",
                             headers={"Content-Disposition": content_disposition(name, "attachment"),
                                      "Cache-Control": "private, no-store"})
