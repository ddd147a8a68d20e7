"""The trainer's checkpoint: one atomically written ``checkpoint.pt`` per fit.

It holds the field, amplitude and optimiser states, the iteration, the loss histories, the
global torch/numpy/python (and CUDA) RNG states, the schedules' own state (the weight average)
and a fingerprint of what must match for it to be resumed.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from shsas_core.common.atomic import atomic_path
from shsas_core.neural.fields.base import ScatteringField
from shsas_core.neural.train.config import TrainConfig
from shsas_core.neural.train.data import TrainingData

CHECKPOINT_NAME = "checkpoint.pt"


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint written by :func:`~shsas_core.neural.train.fit` (a dict; see ``fit``)."""
    return torch.load(Path(path), map_location=map_location, weights_only=False)


def save_checkpoint(checkpoint: dict[str, Any], path: Path) -> None:
    """Write ``checkpoint`` to ``path`` atomically (a crash leaves the previous one)."""
    with atomic_path(path) as tmp:
        torch.save(checkpoint, tmp)


def fingerprint(cfg: TrainConfig, field: torch.nn.Module, data: TrainingData) -> dict[str, Any]:
    """What must match for a checkpoint to be resumed (iters may grow unless the lr decays over
    them; a weight average is checked by the schedule that keeps it)."""
    c = cfg.model_dump(mode="json")
    if cfg.lr_final is None:
        c.pop("iters")
    c.pop("checkpoint_every")
    c.pop("heap_cache")
    c.pop("device")
    # every field backend computes the same maths, so a checkpoint moves between machines and backends
    f = field.config.model_dump(mode="json", exclude={"backend"}) if isinstance(field, ScatteringField) else None
    return {"train": c, "field": f, "pings": data.pings.tolist(), "energy": data.energy}


#: Options TrainConfig no longer has, each with the one behaviour that remains: a checkpoint whose
#: fingerprint names them at these values was made by the same training and still resumes.
RETIRED_OPTIONS: dict[str, object] = {"reg_start": 0, "tv_points": 4096, "learn_amplitude": True,
                                      "progressive_sh_every": None}


def comparable(stored: dict[str, Any] | None) -> dict[str, Any] | None:
    """A stored fingerprint without the retired options that hold their remaining behaviour."""
    if not stored or not isinstance(stored.get("train"), dict):
        return stored
    train = {k: v for k, v in stored["train"].items()
             if not (k in RETIRED_OPTIONS and v == RETIRED_OPTIONS[k])}
    return {**stored, "train": train}


def rng_state() -> dict[str, Any]:
    """The global RNG states (torch, numpy, python, CUDA where present)."""
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None}


def restore_rng_state(state: dict[str, Any]) -> None:
    """Set the global RNGs to ``state`` (from :func:`rng_state`)."""
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if torch.cuda.is_available() and state.get("cuda") is not None:
        torch.cuda.set_rng_state_all(state["cuda"])
