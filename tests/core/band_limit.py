"""Narrowband test data made from a wideband recording: the same scan, filtered to a band.

A narrowband scan's range resolution c / 2B is several times coarser than a wideband one's,
which is what makes its plane of focus hard to find. Filtering a real wideband recording
keeps everything else real (scene, geometry, clutter, noise in band).

The samples and the stored pulse go through the same linear, zero-phase filter, so the
measurement model ``samples = s_PD ⊛ pulse`` still holds after filtering, and ``meta.pulse``
is given the new band (the deconvolution tapers to it; c / 2B follows it).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from shsas_core.survey import Survey

#: Width of the raised-cosine skirts on each side of the passband, Hz.
SKIRT_HZ = 500.0


def band_mask(freq: np.ndarray, lo: float, hi: float, skirt: float = SKIRT_HZ) -> np.ndarray:
    """Zero-phase gain at ``|freq|``: 1 in [lo, hi], raised-cosine skirts ``skirt`` wide, else 0."""
    f = np.abs(freq)
    gain = ((f >= lo) & (f <= hi)).astype(np.float64)
    for edge, side in ((lo, -1), (hi, 1)):
        d = side * (f - edge)  # distance outside the passband
        on = (d > 0) & (d < skirt)
        gain[on] = 0.5 * (1 + np.cos(np.pi * d[on] / skirt))
    return gain


def _filter_rows(x: np.ndarray, fs: float, lo: float, hi: float, out_len: int) -> np.ndarray:
    """Filter real rows with :func:`band_mask`; zero-padded so the filter's tails do not wrap."""
    n = x.shape[-1]
    n_fft = 1 << int(np.ceil(np.log2(2 * max(n, out_len) + int(4 * fs / SKIRT_HZ))))
    spec = np.fft.rfft(x, n_fft, axis=-1) * band_mask(np.fft.rfftfreq(n_fft, 1 / fs), lo, hi)
    return np.fft.irfft(spec, n_fft, axis=-1)[..., :out_len]


def band_limited(survey: Survey, centre_hz: float, width_hz: float) -> Survey:
    """The survey filtered to ``centre_hz ± width_hz / 2`` (real passband samples only).

    The pulse keeps twice its nominal length: a narrow band's filter rings longer than the
    pulse, and the part before t = 0 (the zero-phase filter's leading tail) is dropped, which
    is small next to the pulse's in-band energy for a band inside the chirp's.
    """
    if survey.meta.signal_kind != "real" or survey.samples is None:
        raise ValueError("band_limited needs a survey with real passband samples loaded")
    lo, hi = centre_hz - 0.5 * width_hz, centre_hz + 0.5 * width_hz
    fs = survey.meta.fs
    samples = _filter_rows(survey.samples.astype(np.float64), fs, lo, hi, survey.num_samples)
    pulse = _filter_rows(np.asarray(survey.pulse, dtype=np.float64), fs, lo, hi, 2 * survey.pulse.size)
    old = survey.meta.pulse
    # keep the sweep's direction: an up-chirp stays an up-chirp
    f_start, f_stop = (hi, lo) if old.f_start > old.f_stop else (lo, hi)
    meta = survey.meta.model_copy(update={
        "pulse": old.model_copy(update={"f_start": f_start, "f_stop": f_stop}),
        "attrs": {**survey.meta.attrs, "band_limited_hz": f"{lo:g}..{hi:g}"},
    })
    return dataclasses.replace(survey, samples=samples.astype(np.float32), pulse=pulse, meta=meta, extras={})
