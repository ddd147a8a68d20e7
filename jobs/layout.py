"""Where a job's files live under the data dir (``SHSAS_DATA_DIR``); every path is server-made
from the job id, never from client input::

    <data_dir>/jobs/<id>/input/        the stored survey (canonical HDF5)
    <data_dir>/jobs/<id>/out/          the pipeline's outputs: artifacts, checkpoints, previews
    <data_dir>/jobs/<id>/survey/       the survey view the console plots (written at upload)
    <data_dir>/jobs/<id>/extracts/     re-extractions at other iso levels (made on request)
    <data_dir>/uploads/<random>/       an upload in flight (removed when its request ends)
    <data_dir>/validation-slots/       lock files bounding the validations running at once

Deleting ``jobs/<id>/`` removes everything a job has on disk.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .settings import Settings

INPUT = "input"
OUT = "out"
#: Also the folder name the validation child writes the view under in its work folder.
SURVEY_VIEW = "survey"
EXTRACTS = "extracts"
UPLOADS = "uploads"
VALIDATION_SLOTS = "validation-slots"


def job_dir(settings: Settings, job_id: str) -> Path:
    """The folder holding everything of job ``job_id``."""
    return settings.jobs_dir() / job_id


def job_paths(settings: Settings, job_id: str) -> tuple[Path, Path]:
    """(input dir, output dir) of a job."""
    base = job_dir(settings, job_id)
    return base / INPUT, base / OUT


def survey_view_dir(settings: Settings, job_id: str) -> Path:
    return job_dir(settings, job_id) / SURVEY_VIEW


def extracts_dir(settings: Settings, job_id: str) -> Path:
    return job_dir(settings, job_id) / EXTRACTS


def remove_job_files(settings: Settings, job_id: str) -> None:
    """Delete everything a job has on disk (its input, outputs, view and extractions)."""
    shutil.rmtree(job_dir(settings, job_id), ignore_errors=True)


def uploads_dir(settings: Settings) -> Path:
    return settings.data_dir / UPLOADS


def validation_slots_dir(settings: Settings) -> Path:
    return settings.data_dir / VALIDATION_SLOTS
