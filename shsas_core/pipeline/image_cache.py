"""The job's backprojection image, shared by its methods (the backprojection's volume, the
neural methods' warm start and occupancy grid)."""

from __future__ import annotations

from typing import Any

import numpy as np

from shsas_core.common.progress import ProgressFn, StopFn
from shsas_core.data.survey import Survey
from shsas_core.data.volume import Grid, Volume
from shsas_core.pipeline.job_cache import JobCache


class ImageCache:
    """The job's backprojection image of the training pings on the job's grid, computed on first
    use and kept in the job cache (so a resumed job does not recompute it)."""

    def __init__(self, train: Survey, signals: np.ndarray, grid: Grid, device: Any, cache: JobCache,
                 should_stop: StopFn):
        self._train, self._signals, self._grid = train, signals, grid
        self._device, self._should_stop = device, should_stop
        self._cache = cache
        self._volume: Volume | None = None

    def __call__(self, progress: ProgressFn) -> Volume:
        if self._volume is None:
            arr = self._cache.array("backprojection_image", self._grid.shape)
            if arr is not None:
                self._volume = Volume(self._grid, arr, name="backprojection")
        if self._volume is None:
            from shsas_core.imaging.backprojection import backproject_survey

            vol = backproject_survey(self._train, self._grid, self._signals,
                                     device=self._device, progress=progress, should_stop=self._should_stop)
            self._cache.save_array("backprojection_image", vol.values)
            self._volume = vol
        progress(1.0, "backprojection", {})
        return self._volume
