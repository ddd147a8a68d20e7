"""One job's own log: the lines the worker and the science library log while it runs the job,
kept beside the job's files (``<jobs dir>/<id>/job.log``) for the API's
``GET /reconstructions/{id}/log`` and the console's log view.

A line is ``HH:MM:SS level message`` (UTC). Only records of the thread running the job, or
naming the job (``extra={"job_id": ...}``, e.g. from its heartbeat thread), are kept, so jobs
that share a worker process do not mix. The file stops growing at :data:`MAX_BYTES` with one
closing line: a job that logs every step cannot fill the disk.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

#: The loggers whose records can belong to a job: the service's and the science library's.
LOGGERS = ("shsas", "shsas_core")
#: The most a job's log holds (bytes); later lines are dropped.
MAX_BYTES = 256 * 1024
#: The job log's file name inside the job's folder (beside ``input/`` and ``out/``).
NAME = "job.log"


class _JobHandler(logging.Handler):
    def __init__(self, path: Path, job_id: str) -> None:
        super().__init__(logging.INFO)
        self.path, self.job_id = path, job_id
        self.thread = threading.get_ident()
        self.size = path.stat().st_size if path.exists() else 0  # a retried job adds to its log
        self.full = self.size >= MAX_BYTES

    def emit(self, record: logging.LogRecord) -> None:
        if self.full or not (record.thread == self.thread or getattr(record, "job_id", None) == self.job_id):
            return
        try:
            when = datetime.fromtimestamp(record.created, UTC).strftime("%H:%M:%S")
            text = record.getMessage().replace("\n", " | ")  # one record, one line
            for prefix in (f"job {self.job_id}: ", f"job {self.job_id} "):  # it is this job's log
                text = text.removeprefix(prefix)
            line = f"{when} {record.levelname.lower()} {text}\n".encode(errors="replace")
            if self.size + len(line) > MAX_BYTES - 100:  # room for the closing line
                line, self.full = f"{when} warning the log reached {MAX_BYTES} bytes; later lines are not kept\n".encode(), True
            with open(self.path, "ab") as f:  # handle() holds the handler's lock
                f.write(line)
            self.size += len(line)
        except OSError:  # the job's folder went (deleted mid-run): nothing to keep
            self.full = True


@contextmanager
def job_log(folder: Path, job_id: str) -> Iterator[Path]:
    """Keep the job's log lines in ``folder/job.log`` while the block runs (in the job's thread)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / NAME
    handler = _JobHandler(path, job_id)
    loggers = [logging.getLogger(n) for n in LOGGERS]
    for lg in loggers:
        lg.addHandler(handler)  # at the loggers' own levels: shsas at info, shsas_core as set
    try:
        yield path
    finally:
        for lg in loggers:
            lg.removeHandler(handler)


def read_tail(path: Path, max_lines: int, max_bytes: int) -> tuple[list[str], bool]:
    """The last ``max_lines`` lines of the log within its last ``max_bytes`` bytes, and whether
    earlier lines were left out. No file (the job has not started): no lines."""
    try:
        with open(path, "rb") as f:
            size = f.seek(0, 2)
            f.seek(max(0, size - max_bytes))
            raw = f.read()
    except FileNotFoundError:
        return [], False
    lines = raw.decode(errors="replace").splitlines()
    cut = size > max_bytes
    if cut:
        lines = lines[1:]  # the first is likely a part line
    if len(lines) > max_lines:
        lines, cut = lines[-max_lines:], True
    return lines, cut
