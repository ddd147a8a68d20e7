"""A daemon thread that calls one function at a fixed interval until stopped (the reconciler, the
API's sweeper and a running job's heartbeat)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable


class Periodic:
    """Calls ``tick()`` every ``interval_s`` seconds on a daemon thread named ``name``.

    An exception in ``tick`` is logged on ``log`` as "``what`` failed" and the next tick runs as
    usual: the job store or the broker may be briefly away.
    """

    def __init__(self, name: str, interval_s: float, tick: Callable[[], object], log: logging.Logger,
                 what: str, join_timeout_s: float = 5.0):
        self._interval_s, self._tick, self._log, self._what = interval_s, tick, log, what
        self._join_timeout_s = join_timeout_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)

    def start(self) -> Periodic:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=self._join_timeout_s)

    def _loop(self) -> None:
        while not self._stop.wait(self._interval_s):
            try:
                self._tick()
            except Exception:  # try again next tick
                self._log.exception("%s failed", self._what)
