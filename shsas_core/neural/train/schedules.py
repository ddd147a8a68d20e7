"""What changes over the iterations, as callbacks of the :class:`~shsas_core.neural.train.loop.Trainer`.

Each schedule is a pure function of the iteration (and the config), so a resumed run follows
the same course as an uninterrupted one. A :class:`Callback` is called before and after each
optimiser step, at the end of the loop (also when it is left by an error or a cancel), and once
the final checkpoint is written; what it must carry across a resume it puts in the checkpoint.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from shsas_core.common.errors import ShsasError
from shsas_core.neural.fields.base import ScatteringField
from shsas_core.neural.train.config import TrainConfig
from shsas_core.spec.options import COARSE_TO_FINE_START_RESOLUTION

if TYPE_CHECKING:
    from shsas_core.neural.train.loop import Trainer


class Callback:
    """A schedule of the training loop; every hook does nothing unless overridden."""

    def before_step(self, trainer: Trainer, it: int) -> None:
        """Before iteration ``it``'s loss is computed."""

    def after_step(self, trainer: Trainer, it: int) -> None:
        """After iteration ``it``'s optimiser step."""

    def end(self, trainer: Trainer) -> None:
        """After the loop, however it was left (restore the field's normal state here)."""

    def finish(self, trainer: Trainer) -> None:
        """After the final checkpoint of a completed loop (change the returned field here)."""

    def state(self) -> dict[str, Any]:
        """Entries this schedule adds to the checkpoint."""
        return {}

    def resume(self, checkpoint: dict[str, Any], path: Path) -> None:
        """Restore what :meth:`state` wrote into ``checkpoint`` (read from ``path``)."""


def scheduled_lr(cfg: TrainConfig, it: int) -> float:
    """lr · (lr_final / lr)^(it / (iters - 1)): a pure function of the iteration, so resume is exact."""
    if cfg.lr_final is None or cfg.iters <= 1:
        return cfg.lr
    return cfg.lr * (cfg.lr_final / cfg.lr) ** (it / (cfg.iters - 1))


class LearningRateDecay(Callback):
    """Geometric decay of the learning rate from ``lr`` to ``lr_final`` (:func:`scheduled_lr`)."""

    def __init__(self, cfg: TrainConfig) -> None:
        self.cfg = cfg

    def before_step(self, trainer: Trainer, it: int) -> None:
        for group in trainer.optimizer.param_groups:
            group["lr"] = scheduled_lr(self.cfg, it)


def coarse_start_levels(encoding: Any) -> int:
    """Hash levels on at the start of a coarse-to-fine fit: those of resolution up to
    :data:`COARSE_TO_FINE_START_RESOLUTION` (at least one)."""
    return max(1, sum(r <= COARSE_TO_FINE_START_RESOLUTION for r in encoding.resolutions()))


def active_levels(encoding: Any, fraction: float, it: int, iters: int) -> float:
    """Active hash levels at iteration ``it`` of a coarse-to-fine fit: from
    :func:`coarse_start_levels` up to every level, linearly over the first ``fraction * iters``
    iterations (``SHField.set_active_levels``)."""
    start, n = coarse_start_levels(encoding), encoding.n_levels
    return start + (n - start) * min(1.0, it / max(1.0, fraction * iters))


class CoarseToFine(Callback):
    """The hash levels brought in over the first ``fraction`` of the iterations (:func:`active_levels`).

    Levels follow the running fit's ``iters``: a finished run extended by resuming is past its
    ramp and keeps every level on.
    """

    def __init__(self, field: ScatteringField, fraction: float, iters: int) -> None:
        self.field, self.fraction, self.iters = field, fraction, iters

    def before_step(self, trainer: Trainer, it: int) -> None:
        self.field.set_active_levels(active_levels(self.field.config.encoding, self.fraction, it, self.iters))

    def end(self, trainer: Trainer) -> None:
        self.field.set_active_levels(None)


def average_start(cfg: TrainConfig) -> int:
    """The steps after which the iterates are averaged (the last ``average_last`` of them, at
    least one; ``iters`` when nothing is averaged)."""
    if cfg.average_last is None:
        return cfg.iters
    return cfg.iters - max(1, round(cfg.average_last * cfg.iters))


class WeightAverage(Callback):
    """A running uniform mean of the field's parameters over the last ``average_last`` of the
    steps (torch's ``AveragedModel``), copied into the field once training completes."""

    def __init__(self, field: torch.nn.Module, cfg: TrainConfig) -> None:
        from torch.optim.swa_utils import AveragedModel

        assert cfg.average_last is not None
        self.field, self.cfg = field, cfg
        self.average = AveragedModel(field, use_buffers=False)  # its default: the running uniform mean
        self.start = average_start(cfg)

    def after_step(self, trainer: Trainer, it: int) -> None:
        if it >= self.start:
            self.average.update_parameters(self.field)

    def finish(self, trainer: Trainer) -> None:
        # after the final checkpoint: a resumed run continues from the last iterate, not the mean
        if trainer.iteration > self.start:
            with torch.no_grad():
                for p, q in zip(self.field.parameters(), self.average.module.parameters(), strict=True):
                    p.copy_(q)

    def state(self) -> dict[str, Any]:
        return {"average": self.average.state_dict(), "average_from": self.start}

    def resume(self, checkpoint: dict[str, Any], path: Path) -> None:
        """Restore the average, or start it afresh when the resumed run (more iterations)
        averages a span that begins after the checkpoint."""
        start = int(checkpoint["iteration"])
        if checkpoint.get("average_from") == self.start and checkpoint.get("average") is not None:
            self.average.load_state_dict(checkpoint["average"])
        elif start > self.start:
            frac = self.cfg.average_last
            assert frac is not None  # there is an average to resume
            fix = (f"{math.ceil(start / (1 - frac))} iterations or more" if frac < 1 else "a new output directory")
            raise ShsasError(f"fit: checkpoint {path} is at iteration {start}, past iteration {self.start} "
                             f"where this run's weight average begins (average_last {frac:g} of "
                             f"{self.cfg.iters} iterations); fix: {fix}")


def schedules(field: torch.nn.Module, cfg: TrainConfig) -> list[Callback]:
    """The callbacks ``cfg`` asks for, in the order they run before each step."""
    out: list[Callback] = []
    # a plain module (a test or benchmark stand-in) has no hash levels to bring in
    if cfg.coarse_to_fine is not None and isinstance(field, ScatteringField):
        out.append(CoarseToFine(field, cfg.coarse_to_fine, cfg.iters))
    if cfg.lr_final is not None:
        out.append(LearningRateDecay(cfg))
    if cfg.average_last is not None:
        out.append(WeightAverage(field, cfg))
    return out
