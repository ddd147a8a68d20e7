"""Narrowband test cases made from wideband ones: the same recording seen through a narrower band.

:func:`band_limited` keeps a band of a real-passband survey's samples and of its pulse, and says
so in ``meta.pulse``: the result is what a sonar transmitting only that band would have recorded
(range resolution ``c / 2B`` for the new band ``B``), on the same geometry and the same scene.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.fft as sfft
from scipy.signal import windows

from shsas_core.data.survey import Survey

#: Share of the kept band over which the filter's edges fall (a Tukey taper): a brick wall
#: would ring through the whole record.
EDGE_FRACTION = 0.2


def _band_pass(x: np.ndarray, fs: float, band: tuple[float, float]) -> np.ndarray:
    """Zero-phase band-pass of real rows ``x`` (..., T): a Tukey-tapered band, same length."""
    t = x.shape[-1]
    nfft = sfft.next_fast_len(2 * t)
    f = sfft.rfftfreq(nfft, 1.0 / fs)
    inband = (f >= band[0]) & (f <= band[1])
    w = np.zeros(f.size)
    w[inband] = windows.tukey(int(inband.sum()), alpha=EDGE_FRACTION)
    return sfft.irfft(sfft.rfft(x, nfft, axis=-1) * w, nfft, axis=-1)[..., :t]


def band_limited(survey: Survey, centre_hz: float, bandwidth_hz: float) -> Survey:
    """The survey as if it had been recorded in ``centre ± bandwidth / 2`` only (real samples).

    The pulse is filtered the same way and ``meta.pulse`` gets the new band (the chirp's
    direction kept), so deconvolution and every resolution figure see the narrow band.
    """
    if survey.meta.signal_kind != "real" or survey.samples is None:
        raise ValueError("band_limited needs a real-passband survey with its samples loaded")
    fs = survey.meta.fs
    band = (centre_hz - bandwidth_hz / 2, centre_hz + bandwidth_hz / 2)
    samples = _band_pass(survey.samples.astype(np.float64), fs, band).astype(survey.samples.dtype)
    pulse = _band_pass(np.asarray(survey.pulse, dtype=np.float64), fs, band)
    p = survey.meta.pulse
    down = p.f_stop < p.f_start
    pp = p.model_copy(update={"f_start": band[1] if down else band[0], "f_stop": band[0] if down else band[1]})
    meta = survey.meta.model_copy(update={"pulse": pp, "attrs": {**survey.meta.attrs,
                                                                 "band_limited_hz": f"{band[0]:g}..{band[1]:g}"}})
    return dataclasses.replace(survey, samples=samples, pulse=pulse, meta=meta, extras={})


def narrowband_plane_scene(centre_hz: float = 20e3, bandwidth_hz: float = 5e3, angles: int = 180) -> Survey:
    """A simulated single-height circular scan in a narrow band: an edge-lit plate (points along
    the rim of a 90 x 210 mm rectangle, the real cut-out's size) and the focus scenes' five points,
    all in the plane z = PLANE_Z; no noise. Its range resolution ``c / 2B`` is 34 mm at 5 kHz."""
    from shsas_core.data.survey import PulseParams
    from shsas_core.simulation.scatterers import Scatterers
    from shsas_core.simulation.simulate import SimulationConfig, simulate
    from shsas_core.simulation.trajectory import TrajectoryConfig
    from tests.helpers.focus_scenes import BOX, PLANE_POINTS, PLANE_Z

    hx, hy = 0.045, 0.105
    t = np.linspace(0, 1, 24, endpoint=False)
    rim = np.concatenate([np.column_stack([-hx + 2 * hx * t, np.full_like(t, -hy)]),
                          np.column_stack([np.full_like(t, hx), -hy + 2 * hy * t]),
                          np.column_stack([hx - 2 * hx * t, np.full_like(t, hy)]),
                          np.column_stack([np.full_like(t, -hx), hy - 2 * hy * t])])
    xy = np.concatenate([rim, PLANE_POINTS])
    pts = np.column_stack([xy, np.full(len(xy), PLANE_Z)])
    box = BOX.model_copy(update={"min": (-0.125, -0.125, BOX.min[2]), "max": (0.125, 0.125, BOX.max[2])})
    pulse = PulseParams(f_start=centre_hz + bandwidth_hz / 2, f_stop=centre_hz - bandwidth_hz / 2)
    cfg = SimulationConfig(trajectory=TrajectoryConfig(angles=angles, heights=1, height_min=0.25),
                           pulse=pulse, snr_db=None, scene_box=box)
    return simulate(None, cfg, scatterers=Scatterers(pts))
