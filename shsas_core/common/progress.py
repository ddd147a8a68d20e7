"""Progress reporting and cooperative cancellation shared by the CLI, the worker and tests.

Long routines take ``progress(fraction, stage, metrics)`` and ``should_stop()`` callables.
``fraction`` is in [0, 1] for the current stage, ``stage`` a short name ("deconvolution",
"backprojection", "fit:shsas", ...), ``metrics`` a flat dict of floats (loss, it/s, ...).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

from shsas_core.common.errors import Cancelled

ProgressFn = Callable[[float, str, Mapping[str, float]], None]
StopFn = Callable[[], bool]


def no_progress(fraction: float, stage: str, metrics: Mapping[str, float]) -> None:
    """Progress sink that ignores everything."""


def never_stop() -> bool:
    """Stop predicate that never asks to stop."""
    return False


def check_stop(should_stop: StopFn | None) -> None:
    """Raise :class:`Cancelled` when ``should_stop`` says so; call between steps of long work."""
    if should_stop is not None and should_stop():
        raise Cancelled("cancelled on request")


def sub_progress(progress: ProgressFn, start: float, end: float) -> ProgressFn:
    """Map a child's [0, 1] fraction onto [start, end] of the parent's progress."""

    def child(fraction: float, stage: str, metrics: Mapping[str, float]) -> None:
        progress(start + (end - start) * min(max(fraction, 0.0), 1.0), stage, metrics)

    return child


class TqdmProgress:
    """A ``ProgressFn`` that drives one tqdm bar per stage (used by the CLI)."""

    def __init__(self, disable: bool = False):
        self._bar = None
        self._stage: str | None = None
        self._disable = disable
        self._last = 0.0

    def __call__(self, fraction: float, stage: str, metrics: Mapping[str, float]) -> None:
        from tqdm.auto import tqdm

        if stage != self._stage:
            self.close()
            self._stage = stage
            self._bar = tqdm(total=1000, desc=stage, disable=self._disable, leave=True,
                             bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining} {postfix}")
        assert self._bar is not None
        self._bar.n = round(1000 * min(max(fraction, 0.0), 1.0))
        # Redraw at most ~5 times a second: training calls this every iteration, and in a log
        # file (no terminal) each redraw is another line of text.
        now = time.monotonic()
        if now - self._last < 0.2 and fraction < 1.0:
            return
        self._last = now
        if metrics:
            self._bar.set_postfix({k: f"{v:.4g}" for k, v in metrics.items()}, refresh=False)
        self._bar.refresh()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
