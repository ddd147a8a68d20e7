"""The submit transaction of ``POST /reconstructions``: receive the upload, check the spec and
the caller's quota, validate the survey in a child process, store it under the job's folder,
create the job row and hand the job to its queue. Anything that fails undoes what was done.
"""

from __future__ import annotations

import hashlib
import json
import logging
import uuid
from contextlib import AsyncExitStack

import pydantic
from anyio import to_thread
from fastapi import HTTPException, Request

from jobs.layout import (
    job_paths,
    remove_job_files,
    survey_view_dir,
    uploads_dir,
    validation_slots_dir,
)
from jobs.settings import Settings
from jobs.store import IdempotencyConflict, Job, JobStore
from shsas_core.common.errors import pydantic_fix
from shsas_core.formats.registry import stored_name
from shsas_core.spec.job import ReconstructionSpec
from worker.dispatch import dispatch

from .job_names import job_label
from .quotas import box_of, check_cpu_time, check_spec_cost, hold_slot
from .sweeper import upload_dir
from .uploads import UploadError, receive_upload
from .validation import ValidationsBusy, validate_in_child, validation_slot

log = logging.getLogger("shsas.api")

#: Seconds a client is told to wait (Retry-After) when every validation slot stayed busy.
VALIDATIONS_BUSY_RETRY_S = 10


def spec_error(exc: pydantic.ValidationError) -> str:
    """One line per problem, each naming the spec field and a fix: ``spec.grid: ... (got 9999) (fix: ...)``."""
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(p) for p in err["loc"])
        got = f" (got {err['input']!r})" if "input" in err and err["type"] != "json_invalid" else ""
        fix = pydantic_fix(err, list(ReconstructionSpec.model_fields), "the ReconstructionSpec, shsas_core/spec/job.py")
        parts.append(f"spec{'.' + loc if loc else ''}: {err['msg']}{got}"[:300] + f" (fix: {fix})")
    return "; ".join(parts)


async def submit_job(request: Request, who: str, store: JobStore, settings: Settings,
                     idempotency_key: str | None) -> Job:
    """Receive the upload of ``request``, validate it and its spec, and queue the job: the job
    (with 202 from the route), or the earlier job of the same ``idempotency_key`` and request.

    Raises :class:`UploadError` (4xx/503 with the reason) or HTTPException 503 when every
    validation slot stayed busy. The key's quota slot is held from before validation until the
    job row exists, so concurrent submissions cannot together pass the quota.
    """
    async with AsyncExitStack() as held:
        return await _submit(request, who, store, settings, idempotency_key, held)


async def _submit(request: Request, who: str, store: JobStore, settings: Settings,
                  idempotency_key: str | None, held: AsyncExitStack) -> Job:
    with upload_dir(uploads_dir(settings)) as tmp_dir:
        # "label" (optional): the operator's name for the job, shown in lists and searched
        up = await receive_upload(request, tmp_dir / "upload.part", settings.max_upload_bytes,
                                  text_fields=("spec", "label"))
        if up.path is None:
            raise UploadError(422, "survey: missing file part 'survey' (fix: send the survey file as "
                                   "the multipart field 'survey', e.g. curl -F survey=@scan.h5)")
        if up.size == 0:
            raise UploadError(422, f"survey '{up.display_name}': the uploaded file is empty "
                                   "(fix: check the path given to the upload)")
        label = job_label(up.fields.get("label"))
        if "spec" not in up.fields and not settings.allow_default_spec:
            raise UploadError(422, "spec: missing form field 'spec' (fix: send the ReconstructionSpec as JSON "
                                   "in the multipart field 'spec', e.g. -F 'spec={\"methods\":[\"backprojection\"]}'; "
                                   "-F 'spec={}' runs every default; the operator can accept a missing spec "
                                   "with SHSAS_ALLOW_DEFAULT_SPEC=1)")
        spec_text = up.fields.get("spec", "").strip() or "{}"
        try:
            spec = ReconstructionSpec.model_validate_json(spec_text)
        except pydantic.ValidationError as exc:
            raise UploadError(422, spec_error(exc)) from None
        check_spec_cost(spec, settings)
        check_cpu_time(spec, settings)
        spec_json = spec.model_dump(mode="json")
        request_digest = hashlib.sha256(
            (json.dumps(spec_json, sort_keys=True) + up.sha256).encode()).hexdigest()
        if idempotency_key is not None:
            prior = await to_thread.run_sync(store.find_by_idempotency_key, who, idempotency_key)
            if prior is not None:
                if prior.request_digest != request_digest:
                    raise UploadError(409, f"Idempotency-Key already used for job {prior.id} "
                                           "with a different survey or spec")
                return prior
        await hold_slot(held, store, who, settings)
        upload_path = up.path
        try:
            async with validation_slot(validation_slots_dir(settings), settings.max_concurrent_validations,
                                       settings.validate_wait_s):
                checked = await to_thread.run_sync(lambda: validate_in_child(
                    upload_path, settings.validate_memory_bytes, settings.validate_timeout_s,
                    display_name=up.display_name, spec=spec_json, worker_memory_bytes=settings.worker_memory_bytes,
                    max_ground_truth_elements=settings.max_ground_truth_elements,
                    max_extras_bytes=settings.max_extras_bytes))
        except ValidationsBusy:
            raise HTTPException(503, f"survey: all {settings.max_concurrent_validations} validation slots stayed "
                                     f"busy for {settings.validate_wait_s:g} s (SHSAS_MAX_CONCURRENT_VALIDATIONS); "
                                     "nothing was queued (fix: resubmit after Retry-After seconds)",
                                headers={"Retry-After": str(VALIDATIONS_BUSY_RETRY_S)}) from None
        check_spec_cost(spec, settings, box_of(checked.summary))  # the automatic grid, now known
        check_cpu_time(spec, settings, checked.summary)
        job_id = uuid.uuid4().hex
        in_dir, _ = job_paths(settings, job_id)
        in_dir.mkdir(parents=True)
        # the format registry names the stored input: a canonical upload as it came, any other
        # format as the canonical file its validation converted it to
        input_name = stored_name(checked.format)
        checked.input_path.replace(in_dir / input_name)
        checked.view_dir.replace(survey_view_dir(settings, job_id))
        try:
            job, created = await to_thread.run_sync(lambda: store.create_job(
                owner=who, spec=spec_json, input_digest=up.sha256, input_name=input_name,
                input_bytes=up.size, queue=settings.queue_for(spec.device), job_id=job_id,
                idempotency_key=idempotency_key, request_digest=request_digest,
                client_name=up.filename, label=label))
        except IdempotencyConflict as exc:
            remove_job_files(settings, job_id)
            raise UploadError(409, str(exc)) from None
        if not created:  # a concurrent request with the same key won
            remove_job_files(settings, job_id)
            return job
        try:
            await to_thread.run_sync(dispatch, settings, job)
        except Exception as exc:
            log.exception("could not send job %s to the broker", job.id,
                          extra={"job_id": job.id, "key_id": who, "reason": type(exc).__name__})
            msg = f"the broker is unreachable ({type(exc).__name__}); nothing was queued, resubmit later"
            await to_thread.run_sync(store.fail_queued, job.id, msg)
            remove_job_files(settings, job_id)
            raise UploadError(503, msg) from None
        log.info("job %s submitted", job.id, extra={
            "job_id": job.id, "key_id": who, "queue": job.queue, "methods": spec.methods,
            "grid": spec.grid, "iters": spec.iters, "input_bytes": up.size, "format": checked.format,
            "client_filename": up.display_name})
        return job
