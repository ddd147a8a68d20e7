"""A running job's time left, from the pace its current stage has measured.

The pipeline reports one fraction for the whole job, its stages weighted by fixed guesses of
their cost; the stages run at very different speeds per unit of that fraction (a backprojection
takes seconds for its share, training minutes or hours for the same share). An ETA from the
whole job's average pace therefore drifts all through a stage. Here the pace is the current
stage's own, measured over the later three quarters of the time it has run (so a slow start
fades out) and over at least ten steps (single steps vary a lot on a loaded machine), and the
rest of the job is assumed to go at that pace. The wait for a stage's first step is left out
of its pace. What this does not know is how the later stages' paces differ: a slow short
stage before a quick one (a warm start before a fit of a few iterations) overstates the time
left until the next stage begins, and the figure can jump at each stage change. Until the stage has measured its pace there is no ETA (``None``: "estimating"),
rather than a figure that will swing once the pace is known.
"""

from __future__ import annotations

import itertools

#: A stage must have run this long (s) after its first step before its pace says anything ...
MIN_STAGE_S = 5.0
#: ... and the measured window must hold this many steps (reports that advanced the fraction):
#: on a loaded machine single steps vary by 2-5x.
MIN_STEPS = 10
#: The window is the later part of the stage from this share of its time on, so a slow start
#: fades out while enough steps stay in it to average the noise.
WINDOW_FROM = 0.25
#: Samples kept per stage; older ones are thinned (every other one dropped) past this.
MAX_SAMPLES = 256
#: Samples closer in time than this (s) replace each other (training reports every step).
SAMPLE_EVERY_S = 0.2


class EtaEstimator:
    """Feed it ``update(now, fraction, stage)`` with every progress report; it answers the
    seconds left (``None`` while the current stage has not measured its pace)."""

    def __init__(self) -> None:
        self.stage: str | None = None
        self.samples: list[tuple[float, float]] = []  # (time s, job fraction) within the stage

    def update(self, now: float, fraction: float, stage: str) -> float | None:
        if stage != self.stage:
            self.stage, self.samples = stage, []
        if self.samples and now - self.samples[-1][0] < SAMPLE_EVERY_S:
            self.samples[-1] = (self.samples[-1][0], fraction)
        else:
            self.samples.append((now, fraction))
            if len(self.samples) > MAX_SAMPLES:
                self.samples = self.samples[:1] + self.samples[2::2]
        return self.eta(now, fraction)

    def eta(self, now: float, fraction: float) -> float | None:
        if fraction >= 1.0:
            return 0.0
        # the pace is measured from the stage's first step on: the wait for that first step
        # (a kernel compiling, a cache filling) says nothing about the steps after it
        first = next((i for i, s in enumerate(self.samples) if s[1] > self.samples[0][1]), None)
        if first is None:
            return None
        steps = self.samples[first:]
        t0 = steps[0][0]
        if now - t0 < MIN_STAGE_S:
            return None
        # over the later part of that: from the last sample at or before WINDOW_FROM of it,
        # earlier while the window holds fewer than MIN_STEPS steps
        cut = t0 + (now - t0) * WINDOW_FROM
        i = max(k for k, s in enumerate(steps) if s[0] <= cut)
        while i > 0 and _advances(steps[i:]) < MIN_STEPS:
            i -= 1
        if _advances(steps[i:]) < MIN_STEPS:
            return None
        dt, dp = now - steps[i][0], fraction - steps[i][1]
        if dp <= 0 or dt <= 0:
            return None
        return dt / dp * (1.0 - fraction)


def _advances(samples: list[tuple[float, float]]) -> int:
    """How many of ``samples`` moved the fraction on from the one before."""
    return sum(1 for a, b in itertools.pairwise(samples) if b[1] > a[1])
