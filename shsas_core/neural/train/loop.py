"""The training loop: a :class:`Trainer` with set-up, resume, step, save and finish, and :func:`fit`."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from shsas_core.common.device import resolve_device
from shsas_core.common.errors import Cancelled, ShsasError
from shsas_core.common.heap import heap_cache
from shsas_core.common.optim import adam, load_state
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, no_progress
from shsas_core.neural.fields.base import device_dtype
from shsas_core.neural.fields.occupancy import OccupancyGrid, within
from shsas_core.neural.train.checkpoint import (
    CHECKPOINT_NAME,
    comparable,
    fingerprint,
    load_checkpoint,
    restore_rng_state,
    rng_state,
    save_checkpoint,
)
from shsas_core.neural.train.config import TrainConfig
from shsas_core.neural.train.data import prepare_data
from shsas_core.neural.train.losses import Amplitude, init_amplitude, iteration_loss
from shsas_core.neural.train.schedules import schedules


@dataclasses.dataclass
class FitResult:
    """What :func:`fit` returns.

    Attributes:
        loss_history: total loss per iteration, from iteration 0 (resumed runs include the
            iterations before the resume).
        data_loss_history: the ToF term (relative, see :mod:`shsas_core.neural.train`) per iteration.
        iters_per_s: iterations per second of this call (excludes set-up).
        iterations: iterations completed in total. start_iteration: where this call started.
        amplitude: fitted global scale A (pass to ``render_transients``).
        signal_energy: ``E``, the mean |s|² used to normalise the data term.
        checkpoint_path: last checkpoint written, if any. elapsed_s: wall time of this call.
    """

    loss_history: list[float]
    data_loss_history: list[float]
    iters_per_s: float
    iterations: int
    start_iteration: int
    amplitude: float
    signal_energy: float
    checkpoint_path: str | None
    elapsed_s: float

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class Trainer:
    """One fit of a field to a survey's signals (the arguments are :func:`fit`'s).

    :meth:`run` is :meth:`setup`, :meth:`resume` (or the amplitude's closed-form start), one
    :meth:`step` per iteration with a :meth:`save` every ``checkpoint_every``, and :meth:`finish`.
    The schedules (:mod:`~shsas_core.neural.train.schedules`) are called around each step.
    """

    def __init__(self, field: torch.nn.Module, survey, signals: np.ndarray, config: TrainConfig | None = None,
                 progress: ProgressFn | None = None, should_stop: StopFn | None = None,
                 checkpoint_dir: str | Path | None = None, ping_indices: Sequence[int] | None = None,
                 stage: str = "fit", psf: np.ndarray | None = None,
                 occupancy: OccupancyGrid | None = None) -> None:
        self.field, self.survey, self.signals = field, survey, signals
        self.cfg = config or TrainConfig()
        self.progress = progress or no_progress
        self.should_stop = should_stop
        self.checkpoint_path = Path(checkpoint_dir) / CHECKPOINT_NAME if checkpoint_dir is not None else None
        self.ping_indices, self.stage = ping_indices, stage
        self.psf_kernel, self.occupancy = psf, occupancy
        self.loss_history: list[float] = []
        self.data_loss_history: list[float] = []
        self.start = self.iteration = 0

    def setup(self) -> None:
        """Check and stage the signals, move the field, build the optimiser and the schedules."""
        cfg, field = self.cfg, self.field
        self.t_start = time.perf_counter()
        self.device = device = resolve_device(cfg.device)
        self.data = prepare_data(self.survey, self.signals, self.ping_indices, cfg.uniform_fraction, cfg.target)
        field.to(device)
        self.dtype = device_dtype(field)[1]
        self.callbacks = schedules(field, cfg)
        self.amplitude = Amplitude().to(device)
        self.optimizer = adam([*field.parameters(), self.amplitude.log_amplitude], lr=cfg.lr)
        box = self.survey.meta.scene_box
        self.tv_delta = cfg.tv_delta if cfg.tv_delta is not None else float(np.linalg.norm(box.size)) / 128
        self.fingerprint = fingerprint(cfg, field, self.data)
        if self.occupancy is not None:
            self.occupancy.to(device)
            self.fingerprint["occupancy"] = self.occupancy.digest()
        self.model = within(field, self.occupancy)
        self.psf: torch.Tensor | None = None
        if self.psf_kernel is not None:
            k = np.asarray(self.psf_kernel, dtype=np.complex128).ravel()
            if k.size % 2 != 1 or not np.all(np.isfinite(k)):
                raise ShsasError(f"fit: psf must be a finite kernel of odd length, got {k.size} taps")
            self.psf = torch.as_tensor(k.astype(np.complex64), device=device)
            self.fingerprint["psf"] = [[float(v.real), float(v.imag)] for v in k]

    def resume(self) -> bool:
        """Continue from the checkpoint in ``checkpoint_dir`` if there is one (True); it must
        have been made with the same configuration, survey and field."""
        path = self.checkpoint_path
        if path is None:
            return False
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            return False
        ck = load_checkpoint(path, self.device)
        if comparable(ck.get("fingerprint")) != json.loads(json.dumps(self.fingerprint)):
            raise ShsasError(f"fit: checkpoint {path} was made with a different configuration, "
                             "survey or field (fix: use a new output directory or delete it)")
        self.field.load_state_dict(ck["field"])
        self.amplitude.load_state_dict(ck["amplitude"])
        load_state(self.optimizer, ck["optimizer"])
        for cb in self.callbacks:
            cb.resume(ck, path)
        self.start = self.iteration = int(ck["iteration"])
        self.loss_history, self.data_loss_history = list(ck["loss_history"]), list(ck["data_loss_history"])
        restore_rng_state(ck["rng"])
        return True

    def step(self, it: int) -> None:
        """Iteration ``it``: schedules, loss, one optimiser step, histories."""
        for cb in self.callbacks:
            cb.before_step(self, it)
        loss, data_loss = iteration_loss(self.model, self.amplitude, self.data, self.survey, self.cfg, it,
                                         self.device, self.dtype, self.tv_delta, self.psf)
        loss_value = float(loss.detach())
        if not math.isfinite(loss_value):
            # nothing is stepped or saved: the last checkpoint stays the last good state
            raise ShsasError(f"fit: the loss became {loss_value} at iteration {it} (training "
                             f"diverged; fix: a lower learning rate, e.g. {self.cfg.lr / 3:.3g})")
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        for cb in self.callbacks:
            cb.after_step(self, it)
        self.iteration = it + 1
        self.loss_history.append(loss_value)
        self.data_loss_history.append(float(data_loss.detach()))

    def save(self) -> None:
        """Write the checkpoint (when there is a ``checkpoint_dir``)."""
        if self.checkpoint_path is None:
            return
        ck: dict[str, Any] = {
            "iteration": self.iteration, "field": self.field.state_dict(),
            "amplitude": self.amplitude.state_dict(), "optimizer": self.optimizer.state_dict(),
            "loss_history": self.loss_history, "data_loss_history": self.data_loss_history,
            "rng": rng_state(), "fingerprint": self.fingerprint, "config": self.cfg.model_dump(mode="json"),
            "signal_energy": self.data.energy, "field_config": self.fingerprint["field"],
            "average": None, "average_from": None}
        for cb in self.callbacks:
            ck.update(cb.state())
        save_checkpoint(ck, self.checkpoint_path)

    def finish(self, elapsed_loop: float) -> FitResult:
        """Write the final checkpoint, let the schedules finish the field, and report."""
        self.save()
        for cb in self.callbacks:
            cb.finish(self)
        done = self.iteration - self.start
        return FitResult(loss_history=self.loss_history, data_loss_history=self.data_loss_history,
                         iters_per_s=done / elapsed_loop if done > 0 and elapsed_loop > 0 else 0.0,
                         iterations=self.iteration, start_iteration=self.start,
                         amplitude=float(self.amplitude().detach()), signal_energy=self.data.energy,
                         checkpoint_path=str(self.checkpoint_path) if self.checkpoint_path else None,
                         elapsed_s=time.perf_counter() - self.t_start)

    def run(self) -> FitResult:
        """Set up, resume or start, train to ``iters``, finish."""
        self.setup()
        self.resume()
        cfg = self.cfg
        if self.start == 0:
            init_amplitude(self.model, self.amplitude, self.data, self.survey, cfg, self.device, self.dtype,
                           self.psf)
        t_loop = time.perf_counter()
        with heap_cache(cfg.heap_cache and self.device.type == "cpu"):
            try:
                for it in range(self.start, cfg.iters):
                    check_stop(self.should_stop)
                    self.step(it)
                    rate = (self.iteration - self.start) / max(time.perf_counter() - t_loop, 1e-9)
                    self.progress(self.iteration / cfg.iters, self.stage, {
                        "loss": self.loss_history[-1], "data_loss": self.data_loss_history[-1], "it/s": rate})
                    if self.iteration % cfg.checkpoint_every == 0:
                        self.save()
            except Cancelled:
                self.save()
                raise
            finally:
                for cb in self.callbacks:
                    cb.end(self)
        return self.finish(time.perf_counter() - t_loop)


def fit(field: torch.nn.Module, survey, signals: np.ndarray, config: TrainConfig | None = None,
        progress: ProgressFn | None = None, should_stop: StopFn | None = None,
        checkpoint_dir: str | Path | None = None, ping_indices: Sequence[int] | None = None,
        stage: str = "fit", psf: np.ndarray | None = None,
        occupancy: OccupancyGrid | None = None) -> FitResult:
    """Train ``field`` so that rendered pings match ``signals``.

    Args:
        field: an ``SHField`` (or any module with its ``forward``); trained in place, moved to
            the config's device.
        survey: geometry, time axis, scene box and beam metadata.
        signals: (N, T) complex pulse-deconvolved signals s_PD on the survey's time axis.
        config: :class:`TrainConfig`.
        progress: ``progress(fraction, stage, {"loss", "data_loss", "it/s"})`` once per iteration.
        should_stop: polled between iterations; when it returns True a checkpoint is written
            (if ``checkpoint_dir``) and :class:`~shsas_core.common.errors.Cancelled` is raised.
        checkpoint_dir: where ``checkpoint.pt`` is written every ``checkpoint_every`` iterations
            and at the end; if it already holds a compatible checkpoint, training resumes from it.
        ping_indices: training pings (default all); hold the rest out for novel views.
        stage: stage name reported to ``progress``.
        psf: (2h + 1,) complex point-spread kernel of the deconvolved data (``psf[h]`` at lag 0,
            :func:`~shsas_core.signal.deconv.point_spread`). When given, the rendered impulse response
            of contiguous bins is convolved with it before it is compared with the data, so a thin
            surface explains a PSF-wide echo (``cfg.psf_window`` target bins per ping).
        occupancy: where the field may be non-zero (:mod:`shsas_core.neural.fields.occupancy`); the
            field is rendered as ``within(field, occupancy)``, evaluated only there. Render
            and extract the trained field through the same mask.

    Returns:
        :class:`FitResult`.

    Raises:
        ShsasError: bad signals/config, or a checkpoint from a different configuration.
        Cancelled: ``should_stop()`` returned True.
    """
    return Trainer(field, survey, signals, config, progress, should_stop, checkpoint_dir, ping_indices,
                   stage, psf, occupancy).run()
