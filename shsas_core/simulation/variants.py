"""Surveys unlike the simulator's defaults: the variants a default must hold on.

Each variant changes one thing a reconstruction's defaults must not depend on, against the
default survey (``reference``): records that start at transmit and run long, a scene box much
larger and taller than the object, another sample rate, 5 dB SNR, a narrow band (5 kHz
around 20 kHz: a range resolution of 34 mm against the default band's 8.6 mm) and a wide one
(5-45 kHz: 4.3 mm, 2.5 samples a resolution at 100 kHz). The extraction
test (``tests/core/evaluation/test_extract_variants.py``) and the variants benchmark
(``benchmarks/bench_variants.py``) both simulate them from here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shsas_core.common.errors import ShsasError
from shsas_core.data.survey import PulseParams, SceneBox

#: Variant name -> what it changes, in words.
VARIANTS: dict[str, str] = {
    "reference": "the simulator's defaults",
    "long_from_transmit": "records start at transmit (t0 = 0) and run 700 samples past the scene",
    "large_box": "a scene box 8 cm wider each side and 20 cm taller than the object",
    "sample_rate": "sampled at 250 kHz instead of 100 kHz",
    "snr_5db": "5 dB in-band SNR instead of 20 dB",
    "narrowband": "a 5 kHz chirp around 20 kHz (17.5-22.5 kHz) instead of 10-30 kHz",
    "wideband": "a 40 kHz chirp (5-45 kHz) instead of 10-30 kHz",
}

#: The growth of the large box below and above the object's bounds, m (x, y, z).
LARGE_BOX_GROW_LO = (0.08, 0.08, 0.02)
LARGE_BOX_GROW_HI = (0.08, 0.08, 0.2)


def variant_overrides(name: str, bounds: np.ndarray) -> dict[str, Any]:
    """The :func:`~shsas_core.simulation.simulate.simulate_shape` keywords of variant ``name``.

    Args:
        name: a key of :data:`VARIANTS`.
        bounds: (2, 3) the object's mesh bounds, m (lower and upper corner), for the large box.
    Returns:
        Keyword overrides; ``snr_db`` among them where the variant sets the SNR.
    """
    if name == "reference":
        return {}
    if name == "long_from_transmit":
        return {"guard_samples": 700}
    if name == "large_box":
        lo, hi = np.asarray(bounds, dtype=np.float64)
        return {"scene_box": SceneBox(min=tuple(lo - LARGE_BOX_GROW_LO), max=tuple(hi + LARGE_BOX_GROW_HI))}
    if name == "sample_rate":
        return {"fs": 250e3}
    if name == "snr_5db":
        return {"snr_db": 5.0}
    if name == "narrowband":
        return {"pulse": PulseParams(f_start=17.5e3, f_stop=22.5e3)}
    if name == "wideband":
        return {"pulse": PulseParams(f_start=5e3, f_stop=45e3)}
    raise ShsasError(f"survey variant: unknown name {name!r}; choose from {', '.join(VARIANTS)}")
