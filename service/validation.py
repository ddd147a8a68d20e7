"""Validate an uploaded survey in a separate, resource-limited process (docs/service.md).

The API process never opens uploaded HDF5 itself: a crafted file could exhaust memory or
trip a bug in the HDF5 library. The child gets ``RLIMIT_AS`` (address space) and
``RLIMIT_CPU`` limits (it sets them on itself before importing anything; preexec_fn is
unsafe in a threaded server) plus a wall-clock timeout, and answers one JSON line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from .uploads import UploadError


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


def validate_in_child(path: Path, memory_bytes: int, timeout_s: float, *,
                      display_name: str | None = None, spec: dict | None = None,
                      worker_memory_bytes: int | None = None) -> dict:
    """Validate ``path`` in a child; return ``{"format", "summary"}``. With ``spec`` and
    ``worker_memory_bytes``, the child also refuses a job that would need more memory than that
    (checked from the declared sizes, before any samples are read).

    ``display_name`` (the client's file name) replaces the server's path in every message.

    Raises:
        UploadError: 422 with the validator's message, 413 past the memory limit or over the
        worker memory budget, 422 on timeout.
    """
    try:
        return _validate_in_child(path, memory_bytes, timeout_s, spec, worker_memory_bytes)
    except UploadError as exc:
        raise UploadError(exc.status, name_the_upload(exc.message, path, display_name or path.name)) from None


def _validate_in_child(path: Path, memory_bytes: int, timeout_s: float, spec: dict | None,
                       worker_memory_bytes: int | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k in ("PATH", "PYTHONPATH", "HOME", "LANG", "TMPDIR")}
    # One thread each: the limit is per process and BLAS pools reserve address space per thread.
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", HDF5_USE_FILE_LOCKING="FALSE")
    args = [str(path), str(memory_bytes), str(int(timeout_s) + 1)]
    if spec is not None and worker_memory_bytes is not None:
        args += [str(worker_memory_bytes), json.dumps(spec)]
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "service.validate_child", *args],
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
    return {"format": out["format"], "summary": out["summary"]}
