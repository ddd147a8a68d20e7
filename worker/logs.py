"""The log format of every service process (API, embedded local worker, Celery worker).

One line per event on stderr. ``SHSAS_LOG_FORMAT=json`` (the default) writes one JSON object
per line, so a log shipper can index the fields without parsing prose; ``text`` writes
``time level logger message key=value ...``. Fields passed as ``extra={...}`` to a logging call
(``job_id``, ``status``, ``reason``, ...) become keys of the object.
"""

from __future__ import annotations

import json
import logging
import sys
from datetime import UTC, datetime

#: Attributes every LogRecord has; anything else on a record came from ``extra=``.
_STANDARD = frozenset(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime",
                                                                                "taskName"}
#: The loggers this project writes to (``shsas.api``, ``shsas.access``, ``shsas.worker``, ...).
ROOT = "shsas"


def _extras(record: logging.LogRecord) -> dict[str, object]:
    return {k: v for k, v in vars(record).items() if k not in _STANDARD and not k.startswith("_")}


def _time(record: logging.LogRecord) -> str:
    return datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


class JsonFormatter(logging.Formatter):
    """``{"time", "level", "logger", "message", **extra}`` (plus ``exc`` with a traceback)."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, object] = {"time": _time(record), "level": record.levelname.lower(),
                                  "logger": record.name, "message": record.getMessage(), **_extras(record)}
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


class TextFormatter(logging.Formatter):
    """``time level logger message key=value ...``."""

    def format(self, record: logging.LogRecord) -> str:
        extras = " ".join(f"{k}={v}" for k, v in _extras(record).items())
        line = f"{_time(record)} {record.levelname} {record.name} {record.getMessage()}"
        line = f"{line} {extras}" if extras else line
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


def configure_logging(fmt: str = "json", level: str | int = "info") -> None:
    """Send the ``shsas.*`` loggers to stderr in ``fmt`` at ``level`` (idempotent)."""
    logger = logging.getLogger(ROOT)
    logger.setLevel(level.upper() if isinstance(level, str) else level)
    handler = next((h for h in logger.handlers if getattr(h, "_shsas", False)), None)
    if handler is None:
        handler = logging.StreamHandler(sys.stderr)
        handler._shsas = True  # type: ignore[attr-defined]
        logger.addHandler(handler)
    handler.setFormatter(JsonFormatter() if fmt == "json" else TextFormatter())
    logger.propagate = False  # one line per event, whatever the root logger does
