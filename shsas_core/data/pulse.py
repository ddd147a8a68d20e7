"""Transmitted pulse: linear-frequency-modulated (LFM) chirp with a taper window.

``p(t) = w(t) cos(2π (f0 t + ½ α t²))``, ``α = (f1 - f0) / T_dur``, ``t`` in [0, T_dur).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import windows


def lfm_pulse(
    f_start: float,
    f_stop: float,
    duration: float,
    fs: float,
    window: str = "tukey",
    window_param: float = 0.1,
) -> np.ndarray:
    """Sample the real LFM pulse.

    Args:
        f_start, f_stop: start and stop frequency in Hz (f_stop < f_start gives a down-chirp).
        duration: pulse length in seconds.
        fs: sample rate in Hz.
        window: ``"tukey"`` (``window_param`` = taper ratio), ``"hann"``, ``"taylor"``
            (``window_param`` = sidelobe level in dB, default 35 when 0) or ``"rect"``.
        window_param: parameter of the window.

    Returns:
        (P,) float64 samples, ``P = round(duration * fs)``.
    """
    n = max(round(duration * fs), 1)
    t = np.arange(n) / fs
    alpha = (f_stop - f_start) / duration
    chirp = np.cos(2 * np.pi * (f_start * t + 0.5 * alpha * t**2))
    return chirp * taper(n, window, window_param)


def taper(n: int, window: str = "tukey", window_param: float = 0.1) -> np.ndarray:
    """Window of length ``n`` by name (see :func:`lfm_pulse`)."""
    window = window.lower()
    if window == "tukey":
        return windows.tukey(n, alpha=window_param, sym=True)
    if window == "hann":
        return windows.hann(n, sym=True)
    if window == "taylor":
        return windows.taylor(n, sll=window_param or 35.0, sym=True)
    if window in ("rect", "none", "boxcar"):
        return np.ones(n)
    raise ValueError(f"unknown window '{window}' (use tukey, hann, taylor or rect)")
