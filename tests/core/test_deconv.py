"""Pulse deconvolution on simulated traces: impulses at the true delays, lower sidelobes."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.fft

from shsas_core.deconv import DeconvConfig, deconvolve, wiener_deconvolve
from shsas_core.errors import Cancelled
from shsas_core.signal import analytic_signal, baseband, matched_filter
from shsas_core.survey import Survey, SurveyMeta, default_pulse
from tests.conftest import circular_geometry
from tests.core.echoes import delayed_pulse, peak_sidelobe_db

FS = 100e3
T0 = 3e-3


def _trace_survey(delays, amps, t=800, n=2, kind="real", noise=0.0, seed=0):
    meta = SurveyMeta(fs=FS)
    pulse = default_pulse(meta)
    x = np.stack([delayed_pulse(pulse, np.asarray(delays), np.asarray(amps), T0, t, FS) for _ in range(n)])
    x += noise * np.random.default_rng(seed).standard_normal(x.shape)
    tx, rx = circular_geometry(n)
    t0 = np.full(n, T0)
    samples = x.astype(np.float32)
    if kind == "baseband":
        meta = meta.model_copy(update={"signal_kind": "baseband", "carrier_hz": 20e3})
        samples = baseband(analytic_signal(x), t0, FS, 20e3)
    return Survey(tx=tx, rx=rx, samples=samples, t0=t0, meta=meta, pulse=pulse)


def _peaks(y, k):
    """Indices of the k largest local maxima of |y|, with parabolic sub-sample refinement."""
    a = np.abs(y)
    loc = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])) + 1
    top = loc[np.argsort(a[loc])[::-1][:k]]
    out = []
    for i in sorted(top):
        den = a[i - 1] - 2 * a[i] + a[i + 1]
        out.append(i + (0.5 * (a[i - 1] - a[i + 1]) / den if den else 0.0))
    return np.array(out), a[sorted(top)]


@pytest.mark.parametrize("kind", ["real", "baseband"])
def test_wiener_recovers_impulses_at_true_delays(kind):
    delays = np.array([3.6e-3, 4.1037e-3, 5.2e-3])
    amps = np.array([1.0, 0.6, 0.8])
    s = _trace_survey(delays, amps, kind=kind)
    y = deconvolve(s, DeconvConfig(method="wiener"))
    assert y.shape == s.shape and y.dtype == np.complex64
    idx, mag = _peaks(y[0], 3)
    np.testing.assert_allclose(T0 + idx / FS, delays, atol=0.1 / FS)
    # normalised so an impulse of amplitude A gives a peak of about A
    np.testing.assert_allclose(mag, amps, rtol=0.05)


def test_wiener_sidelobes_are_lower_than_matched_filter():
    """Single echo: the LFM matched filter has about -14 dB peak sidelobes; the default
    (Taylor-tapered) Wiener output has below -30 dB."""
    s = _trace_survey([4.5e-3], [1.0])
    psl_mf = peak_sidelobe_db(matched_filter(s)[0])
    psl_w = peak_sidelobe_db(deconvolve(s)[0])
    assert -16 < psl_mf < -12
    assert psl_w < -30
    assert psl_w < psl_mf - 15
    # the untapered Wiener filter is the narrowest but has sinc-like -13 dB sidelobes
    assert peak_sidelobe_db(deconvolve(s, DeconvConfig(taper="rect"))[0]) > -15


def test_wiener_is_robust_to_noise():
    s = _trace_survey([4.0e-3, 4.8e-3], [1.0, 0.5], noise=0.05)
    y = deconvolve(s)
    idx, _ = _peaks(y[0], 2)
    np.testing.assert_allclose(T0 + idx / FS, [4.0e-3, 4.8e-3], atol=0.2 / FS)


def test_wiener_equals_frequency_domain_definition():
    rng = np.random.default_rng(0)
    sig = rng.standard_normal((2, 100)) + 1j * rng.standard_normal((2, 100))
    rep = rng.standard_normal(20) + 1j * rng.standard_normal(20)
    y = wiener_deconvolve(sig, rep, 1.0, (-0.5, 0.5), noise_level=0.1, taper="rect")
    nfft = scipy.fft.next_fast_len(119)
    p = np.fft.fft(rep, nfft)
    pw = np.abs(p) ** 2
    h = np.conj(p) / (pw + 0.1 * pw.max())
    gain = np.sum(pw / (pw + 0.1 * pw.max())) / nfft
    want = np.fft.ifft(np.fft.fft(sig, nfft) * h / gain)[:, :100]
    np.testing.assert_allclose(y, want, atol=1e-5)


def test_none_and_cancel():
    s = _trace_survey([4e-3], [1.0])
    np.testing.assert_allclose(deconvolve(s, DeconvConfig(method="none")), analytic_signal(s.samples), atol=1e-6)
    with pytest.raises(Cancelled):
        deconvolve(s, should_stop=lambda: True)
