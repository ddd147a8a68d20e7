"""Signal chain: analytic signal vs scipy, matched-filter delays, basebanding, cropping."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from shsas_core.common.errors import ShsasError
from shsas_core.data.geometry import two_way_range_bounds
from shsas_core.data.survey import Survey, SurveyMeta, default_pulse
from shsas_core.signal.chain import (
    analytic_samples,
    analytic_signal,
    baseband,
    correlate,
    crop_to_scene,
    matched_filter,
    passband,
    pulse_replica,
)
from tests.conftest import circular_geometry
from tests.helpers.echoes import delayed_pulse, point_echoes

FS = 100e3


@pytest.mark.parametrize("n", [257, 256])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_analytic_signal_matches_scipy(n, dtype):
    x = np.random.default_rng(1).standard_normal((3, n)).astype(dtype)
    got = analytic_signal(x)
    ref = scipy.signal.hilbert(x.astype(np.float64), axis=-1)
    tol = 1e-5 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(got, ref, atol=tol * np.abs(ref).max())
    assert got.dtype == (np.complex64 if dtype == np.float32 else np.complex128)
    # along another axis too
    np.testing.assert_allclose(analytic_signal(x.T, axis=0), scipy.signal.hilbert(x.T.astype(np.float64), axis=0),
                               atol=tol * np.abs(ref).max())


def test_analytic_of_cosine_is_complex_exponential():
    k = np.arange(1000)
    x = np.cos(2 * np.pi * 50 * k / 1000)  # whole number of cycles: exact
    np.testing.assert_allclose(analytic_signal(x), np.exp(2j * np.pi * 50 * k / 1000), atol=1e-12)


def _survey(samples, t0, kind="real", **kw):
    meta = SurveyMeta(fs=FS, signal_kind=kind, **kw)
    n = samples.shape[0]
    tx, rx = circular_geometry(n)
    return Survey(tx=tx, rx=rx, samples=samples, t0=t0, meta=meta, pulse=default_pulse(meta))


@pytest.mark.parametrize("tau", [4.00e-3, 4.0123e-3, 4.31e-3])
def test_matched_filter_peaks_at_delay(tau):
    meta = SurveyMeta(fs=FS)
    pulse = default_pulse(meta)
    t0 = 3e-3
    x = delayed_pulse(pulse, np.array([tau]), np.array([1.0]), t0, 600, FS)
    s = _survey(np.stack([x, x]).astype(np.float32), np.full(2, t0))
    mf = matched_filter(s)
    a = np.abs(mf[0])
    k = int(np.argmax(a))
    # parabolic refinement of the peak position, samples
    frac = 0.5 * (a[k - 1] - a[k + 1]) / (a[k - 1] - 2 * a[k] + a[k + 1])
    est = t0 + (k + frac) / FS
    assert abs(est - tau) < 0.1 / FS
    # peak magnitude ≈ pulse energy for a unit echo
    assert a[k] == pytest.approx(np.sum(pulse**2), rel=0.05)


def test_matched_filter_real_and_analytic_input_agree():
    meta = SurveyMeta(fs=FS)
    pulse = default_pulse(meta)
    x = np.stack([delayed_pulse(pulse, np.array([d]), np.array([1.0]), 3e-3, 500, FS)
                  for d in (3.5e-3, 4.2e-3)]).astype(np.float32)
    real = _survey(x, np.full(2, 3e-3))
    ana = _survey(analytic_signal(x), np.full(2, 3e-3), kind="analytic")
    a, b = matched_filter(real), matched_filter(ana)
    # real part of the real-input result is exactly the plain real cross-correlation
    ref = np.stack([np.correlate(np.concatenate([row, np.zeros(pulse.size)]), pulse, "valid")[:500]
                    for row in x.astype(np.float64)])
    np.testing.assert_allclose(a.real, ref, atol=1e-5 * np.abs(ref).max())
    # the Hilbert transform of a finite 500-sample window differs from the ideal one by ~0.2%
    # of the peak (circular FFT), so analytic input agrees to that level, not to float precision
    np.testing.assert_allclose(a, b, atol=5e-3 * np.abs(a).max())
    assert np.abs(a - b).max() < 0.05 * np.abs(b).max()


def test_baseband_matched_filter_is_baseband_of_passband():
    meta = SurveyMeta(fs=FS)
    pulse = default_pulse(meta)
    t0 = np.array([3e-3, 3.1e-3])
    x = np.stack([delayed_pulse(pulse, np.array([4e-3]), np.array([1.0]), t, 500, FS) for t in t0])
    fc = 20e3
    sb = baseband(analytic_signal(x), t0, FS, fc)
    bb = _survey(sb, t0, kind="baseband", carrier_hz=fc)
    pb = _survey(analytic_signal(x).astype(np.complex64), t0, kind="analytic")
    want = baseband(matched_filter(pb), t0, FS, fc)
    np.testing.assert_allclose(matched_filter(bb), want, atol=1e-4 * np.abs(want).max())


def test_baseband_roundtrip_and_tone():
    t0 = np.array([1e-3, 2.5e-3])
    k = np.arange(400)
    tone = np.exp(2j * np.pi * 20e3 * (t0[:, None] + k / FS))
    b = baseband(tone, t0, FS, 20e3)
    np.testing.assert_allclose(b, np.ones_like(b), atol=1e-5)  # a tone at f_c becomes DC
    np.testing.assert_allclose(passband(b, t0, FS, 20e3), tone, atol=1e-5)
    with pytest.raises(ShsasError):
        baseband(np.ones((2, 4)), t0, FS, 20e3)


def test_correlate_is_linear_not_circular():
    rng = np.random.default_rng(0)
    s = rng.standard_normal((2, 64)) + 1j * rng.standard_normal((2, 64))
    r = rng.standard_normal(9) + 1j * rng.standard_normal(9)
    got = correlate(s, r)
    want = np.array([[np.sum(row[k : k + 9] * np.conj(r[: len(row[k : k + 9])])) for k in range(64)] for row in s])
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_crop_to_scene_keeps_the_echo_and_shifts_t0():
    meta = SurveyMeta(fs=FS)
    n, t = 6, 2000
    tx, rx = circular_geometry(n)
    t0 = np.full(n, 1e-3)
    target = np.array([[0.03, -0.02, 0.05]])
    x = point_echoes(default_pulse(meta), tx, rx, t0, t, FS, meta.sound_speed, target)
    s = Survey(tx=tx, rx=rx, samples=x, t0=t0, meta=meta, pulse=default_pulse(meta))
    mf = matched_filter(s)
    cropped, t0c = crop_to_scene(s, mf)
    assert cropped.shape[0] == n and cropped.shape[1] < t
    start = np.round((t0c - t0) * FS).astype(int)
    for i in range(n):
        np.testing.assert_array_equal(cropped[i], mf[i, start[i] : start[i] + cropped.shape[1]])
    # the echo peak is inside the window, at the same absolute time
    r_min, r_max = two_way_range_bounds(tx, rx, meta.scene_box)
    for i in range(n):
        k = np.argmax(np.abs(cropped[i]))
        tau = np.linalg.norm(target - tx[i]) + np.linalg.norm(target - rx[i])
        assert abs(t0c[i] + k / FS - tau / meta.sound_speed) <= 1 / FS
        assert t0c[i] <= r_min[i] / meta.sound_speed
        assert t0c[i] + (cropped.shape[1] - 1) / FS >= r_max[i] / meta.sound_speed


def test_analytic_samples_checks_kind():
    s = _survey(np.zeros((2, 300), np.float32) + 1, np.full(2, 3e-3))
    assert analytic_samples(s).dtype == np.complex64
    assert np.iscomplexobj(pulse_replica(s))
    s.samples = None
    with pytest.raises(ShsasError, match="not loaded"):
        analytic_samples(s)


def _polls_until(n: int):
    """A should_stop that says stop at its ``n``-th call, and counts its calls."""
    calls = []

    def should_stop() -> bool:
        calls.append(1)
        return len(calls) >= n

    return should_stop, calls


def test_analytic_samples_of_long_pings_poll_between_blocks_and_match_scipy() -> None:
    """Twelve pings of a million samples (the longest a survey may have): four pings per block
    (not one block of all of them), a cancel between blocks, and the blocked result equal to
    scipy.signal.hilbert row by row."""
    from shsas_core.common.errors import Cancelled
    from shsas_core.signal.chain import BLOCK_SAMPLES, analytic_samples, row_block
    from tests.conftest import make_survey

    t = 1_000_000
    assert row_block(t) == BLOCK_SAMPLES // t == 4 and row_block(512) == 1024
    survey = make_survey(n=12, t=t)
    stop, calls = _polls_until(10**9)
    out = analytic_samples(survey, stop)
    assert len(calls) == 3
    np.testing.assert_allclose(out[2], scipy.signal.hilbert(survey.samples[2].astype(np.float64)),
                               atol=2e-5 * float(np.abs(out[2]).max()))
    stop, calls = _polls_until(2)
    with pytest.raises(Cancelled):
        analytic_samples(survey, stop)
    assert len(calls) == 2  # stopped after one of three blocks
