"""Validate an uploaded survey in a separate, resource-limited process (docs/service.md).

The API process never opens an uploaded survey itself: a crafted file could exhaust memory or
trip a bug in the HDF5 library. The child gets ``RLIMIT_AS`` (address space), ``RLIMIT_CPU``
and ``RLIMIT_FSIZE`` limits (it sets them on itself before importing anything; preexec_fn is
unsafe in a threaded server) plus a wall-clock timeout, and answers one JSON line. At most
``SHSAS_MAX_CONCURRENT_VALIDATIONS`` children run at once (:func:`validation_slot`).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import anyio

from .uploads import UploadError

#: How often a submission waiting for a validation slot tries again.
SLOT_POLL_S = 0.1


def name_the_upload(message: str, path: Path, display_name: str) -> str:
    """``message`` with the server's path replaced by the client's file name, which it then names.

    The validator only sees ``upload.part`` in a temporary folder; a user who uploads several
    files needs to know which one is meant, and the server's folders are none of their business.
    """
    message = message.replace(str(path), display_name).replace(str(path.parent) + os.sep, "")
    message = message.replace(path.name, display_name)
    if f"'{display_name}'" in message:
        return message
    return f"survey '{display_name}': {message.removeprefix('survey: ')}"


@dataclass
class Checked:
    """What validation found and made: the format, the ``shsas info`` summary, the file to
    store as the job's input (the upload itself, or its canonical conversion) and the folder
    holding the survey view."""

    format: str
    summary: dict
    input_path: Path
    view_dir: Path


def validate_in_child(path: Path, memory_bytes: int, timeout_s: float, *,
                      display_name: str | None = None, spec: dict | None = None,
                      worker_memory_bytes: int | None = None,
                      max_ground_truth_elements: int, max_extras_bytes: int) -> Checked:
    """Validate ``path`` in a child; with ``spec`` and ``worker_memory_bytes``, the child also
    refuses a job that would need more memory than that (checked from the declared sizes,
    before any samples are read).

    Everything the child writes lies in ``path``'s folder (the upload's own, removed when the
    request ends and swept when its process died): the canonical conversion and the survey
    view in ``checked/``, and its ``TMPDIR`` in ``tmp/``, so a child that exits, times out or
    is killed leaves nothing elsewhere. ``display_name`` (the client's file name) replaces the
    server's path in every message.

    Raises:
        UploadError: 422 with the validator's message, 413 past the memory limit, over the
        worker memory budget or over the caps on ground-truth meshes and extras, 422 on timeout.
    """
    try:
        return _validate_in_child(path, memory_bytes, timeout_s, spec, worker_memory_bytes,
                                  max_ground_truth_elements, max_extras_bytes, display_name)
    except UploadError as exc:
        raise UploadError(exc.status, name_the_upload(exc.message, path, display_name or path.name)) from None


def _validate_in_child(path: Path, memory_bytes: int, timeout_s: float, spec: dict | None,
                       worker_memory_bytes: int | None, max_ground_truth_elements: int,
                       max_extras_bytes: int, display_name: str | None) -> Checked:
    out_dir = path.parent / "checked"
    cfg = {"path": str(path), "memory_bytes": memory_bytes, "cpu_s": int(timeout_s) + 1, "out_dir": str(out_dir),
           "max_ground_truth_elements": max_ground_truth_elements, "max_extras_bytes": max_extras_bytes,
           "display_name": display_name,
           "budget": worker_memory_bytes if spec is not None else None,
           "spec": json.dumps(spec) if spec is not None and worker_memory_bytes is not None else None}
    out = _run_child(cfg, path.parent, timeout_s)
    from jobs.layout import SURVEY_VIEW

    from .validate_child import CONVERTED_NAME

    return Checked(format=out["format"], summary=out["summary"],
                   input_path=out_dir / CONVERTED_NAME if out.get("converted") else path,
                   view_dir=out_dir / SURVEY_VIEW)


def view_in_child(path: Path, work: Path, memory_bytes: int, timeout_s: float, *,
                  max_ground_truth_elements: int) -> Path:
    """Write the survey view of the stored survey ``path`` in a child (as validation would have);
    everything the child writes lies in ``work``. Returns the view's folder.

    Raises:
        UploadError: the child's refusal, or the time limit.
    """
    from jobs.layout import SURVEY_VIEW


    out_dir = work / "checked"
    cfg = {"path": str(path), "memory_bytes": memory_bytes, "cpu_s": int(timeout_s) + 1, "out_dir": str(out_dir),
           "max_ground_truth_elements": max_ground_truth_elements, "max_extras_bytes": 1 << 62,
           "view_only": True}
    _run_child(cfg, work, timeout_s)
    return out_dir / SURVEY_VIEW


def _run_child(cfg: dict, work: Path, timeout_s: float) -> dict:
    """Run :mod:`service.validate_child` on ``cfg`` with its output and ``TMPDIR`` in ``work``."""
    out_dir, tmp = Path(cfg["out_dir"]), work / "tmp"
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k in ("PATH", "PYTHONPATH", "HOME", "LANG")}
    # One thread each: the limit is per process and BLAS pools reserve address space per thread.
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", HDF5_USE_FILE_LOCKING="FALSE",
               TMPDIR=str(tmp))
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "service.validate_child", json.dumps(cfg)],
            capture_output=True, timeout=timeout_s, env=env, cwd=str(Path(__file__).resolve().parents[1]),
            check=False)
    except subprocess.TimeoutExpired:
        raise UploadError(422, f"survey: validation took longer than {timeout_s:g} s "
                               "(SHSAS_VALIDATE_TIMEOUT_S); the file is too large or malformed "
                               "(fix: check it with `shsas info`, or upload a smaller survey)") from None
    line = proc.stdout.decode("utf-8", "replace").strip().splitlines()[-1:] or [""]
    try:
        out = json.loads(line[0])
    except json.JSONDecodeError:
        if proc.returncode < 0 or b"MemoryError" in proc.stderr or b"Cannot allocate" in proc.stderr:
            raise UploadError(413, "survey: validating it needs more memory than SHSAS_VALIDATE_MEMORY_BYTES "
                                   "allows (fix: upload a smaller survey, or ask the operator to raise "
                                   "the limit)") from None
        tail = proc.stderr.decode("utf-8", "replace").strip().splitlines()[-1:] or ["no output"]
        raise UploadError(422, f"file: could not be read as a survey (validator exited {proc.returncode}: "
                               f"{tail[0][:300]}) (fix: check it with `shsas info`)") from None
    if not out.get("ok"):
        raise UploadError(int(out.get("status", 422)), str(out.get("error")))
    return out


class ValidationsBusy(Exception):
    """Every validation slot stayed taken for the whole wait."""


@contextlib.asynccontextmanager
async def validation_slot(folder: Path, slots: int, wait_s: float) -> AsyncIterator[None]:
    """Hold one of ``slots`` validation slots for the block, waiting up to ``wait_s`` for one.

    A slot is an ``flock`` on ``folder/slot-<i>``: the bound holds across every API process
    that shares the data dir, and the kernel frees a slot whose process died.

    Raises:
        ValidationsBusy: no slot came free within ``wait_s``.
    """
    folder.mkdir(parents=True, exist_ok=True)
    deadline = time.monotonic() + wait_s
    while True:
        for i in range(slots):
            fd = os.open(folder / f"slot-{i}", os.O_CREAT | os.O_RDWR, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            try:
                yield
            finally:
                os.close(fd)  # drops the lock
            return
        if time.monotonic() >= deadline:
            raise ValidationsBusy
        await anyio.sleep(SLOT_POLL_S)
