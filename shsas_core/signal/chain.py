"""Signal chain of one survey: analytic signal, pulse replica, matched filter, basebanding, cropping.

Conventions (every function here and in ``deconv`` / ``backprojection`` follows them):

* A ping's samples ``s[k]`` are taken at times ``t0 + k / fs`` seconds after transmit.
* The pulse ``p[m]`` starts at ``m = 0`` (time 0 = start of transmission), so an echo from a
  two-way path ``r`` is ``A p(t - r/c)``: it *starts* at ``τ = r/c``.
* The matched filter is the correlation with the pulse, indexed by the lag of the pulse start,
  so the echo above peaks at ``τ`` on the ping's own time axis (no group-delay shift needed
  afterwards; the group delay of the pulse is accounted for by correlating rather than
  convolving).
* "analytic" means the FFT Hilbert analytic signal (``scipy.signal.hilbert`` convention):
  real part = the real signal, spectrum zero at negative frequencies, doubled at positive ones.
* "baseband" means ``s_a(t) · exp(-j 2π f_c t)`` with ``t`` the absolute time after transmit,
  so ``s_a(τ) = s_b(τ) · exp(+j 2π f_c τ)`` (the phase term of backprojection).
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import StopFn, check_stop
from shsas_core.data.geometry import two_way_range_bounds
from shsas_core.data.survey import SceneBox, Survey, sample_times


def analytic_signal(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """FFT Hilbert analytic signal of a real array along ``axis``.

    Same definition as ``scipy.signal.hilbert`` (no padding): positive frequencies doubled,
    negative ones zeroed, DC and (even length) Nyquist kept once.

    Args:
        x: real array, any shape; complex input is returned unchanged (already analytic).
    Returns:
        complex array of the same shape (complex64 for float32 input, complex128 otherwise).
    """
    x = np.asarray(x)
    if np.iscomplexobj(x):
        return x
    n = x.shape[axis]
    if n == 0:
        raise ShsasError("analytic_signal: empty signal")
    spec = sfft.fft(x, axis=axis)
    h = np.zeros(n)
    if n % 2 == 0:
        h[0] = h[n // 2] = 1.0
        h[1 : n // 2] = 2.0
    else:
        h[0] = 1.0
        h[1 : (n + 1) // 2] = 2.0
    shape = [1] * x.ndim
    shape[axis] = n
    out = sfft.ifft(spec * h.reshape(shape), axis=axis)
    return out.astype(np.complex64 if x.dtype == np.float32 else np.complex128)


def pulse_replica(survey: Survey) -> np.ndarray:
    """(P,) complex128 analytic replica of the survey's transmitted pulse (starts at t = 0)."""
    p = np.asarray(survey.pulse)
    if np.iscomplexobj(p):
        return p.astype(np.complex128)
    return analytic_signal(p.astype(np.float64))


def replica_in_frame(survey: Survey) -> np.ndarray:
    """(P,) complex128 replica of the pulse in the frame of the survey's samples (starts at t = 0).

    A real pulse is the passband pulse: made analytic and, for baseband data, basebanded
    relative to its own start. A complex pulse is taken as it is: analytic passband, or for
    baseband data already basebanded like the samples (docs/formats.md; the SVSS importer
    stores it so). Basebanding a basebanded pulse again would move it out of the band.
    """
    rep = pulse_replica(survey)
    if survey.meta.signal_kind == "baseband" and not np.iscomplexobj(survey.pulse):
        m = np.arange(rep.size) / survey.meta.fs
        rep = rep * np.exp(-2j * np.pi * float(survey.meta.carrier_hz) * m)
    return rep


def baseband(signals: np.ndarray, t0: np.ndarray, fs: float, carrier_hz: float) -> np.ndarray:
    """Shift analytic passband signals to complex baseband: ``s · exp(-j 2π f_c t)``.

    Args:
        signals: (N, T) complex analytic passband samples.
        t0: (N,) time of the first sample of each ping, s.
        fs: sample rate, Hz.
        carrier_hz: carrier f_c, Hz.
    Returns:
        (N, T) complex64 baseband samples on the same time axis.
    """
    signals = np.asarray(signals)
    if not np.iscomplexobj(signals):
        raise ShsasError("baseband: needs complex analytic samples (call analytic_signal first)")
    return _shift(signals, t0, fs, -carrier_hz)


def passband(signals: np.ndarray, t0: np.ndarray, fs: float, carrier_hz: float) -> np.ndarray:
    """Inverse of :func:`baseband`: ``s_b · exp(+j 2π f_c t)``; (N, T) complex64."""
    return _shift(np.asarray(signals), t0, fs, carrier_hz)


#: Rows per block in the whole-survey transforms below: bounds the float64/complex128
#: temporaries (a 43,200-ping survey would otherwise need several GB of them at once).
ROW_BLOCK = 1024
#: Samples per block at most (fewer rows for long pings): a block's FFTs take a fraction of a
#: second, so a cancel or a time limit polled between blocks lands within about a second even
#: for a survey of a few pings of millions of samples.
BLOCK_SAMPLES = 1 << 22


def row_block(samples_per_row: int) -> int:
    """Rows per block for rows of ``samples_per_row`` samples (1 to ``ROW_BLOCK``)."""
    return max(1, min(ROW_BLOCK, BLOCK_SAMPLES // max(samples_per_row, 1)))


def _shift(signals: np.ndarray, t0: np.ndarray, fs: float, freq: float) -> np.ndarray:
    """``signals · exp(j 2π freq t)`` on each ping's absolute time axis, block by block."""
    t0 = np.asarray(t0, dtype=np.float64)
    out = np.empty(signals.shape, np.complex64)
    for a in range(0, signals.shape[0], ROW_BLOCK):
        t = sample_times(t0[a : a + ROW_BLOCK], fs, signals.shape[-1])
        out[a : a + ROW_BLOCK] = signals[a : a + ROW_BLOCK] * np.exp(2j * np.pi * freq * t)
    return out


def analytic_samples(survey: Survey, should_stop: StopFn | None = None) -> np.ndarray:
    """The survey's samples as complex: real -> analytic passband; analytic/baseband unchanged.

    ``should_stop`` is polled between blocks of rows (:func:`row_block`). Returns (N, T) complex64.
    """
    if survey.samples is None:
        raise ShsasError("survey samples were not loaded (read the survey with load_samples=True)")
    s = survey.samples
    if survey.meta.signal_kind == "real":
        if np.iscomplexobj(s):
            raise ShsasError("pings/samples: complex samples but meta.signal_kind is 'real'")
        out = np.empty(s.shape, np.complex64)
        step = row_block(s.shape[-1])
        for a in range(0, s.shape[0], step):  # bounded temporaries, and a cancel between blocks
            check_stop(should_stop)
            out[a : a + step] = analytic_signal(s[a : a + step].astype(np.float32))
        return out
    if not np.iscomplexobj(s):
        raise ShsasError(f"pings/samples: real samples but meta.signal_kind is '{survey.meta.signal_kind}'")
    return s.astype(np.complex64)


def correlate(signals: np.ndarray, replica: np.ndarray) -> np.ndarray:
    """Linear (not circular) correlation of each row with ``replica`` at lags 0..T-1.

    ``y[n, k] = Σ_m signals[n, k + m] · conj(replica[m])`` (samples past the end count as 0).

    Args:
        signals: (N, T) complex or real.
        replica: (P,) complex or real.
    Returns:
        (N, T) complex64.
    """
    signals = np.atleast_2d(signals)
    t, p = signals.shape[-1], replica.shape[-1]
    nfft = sfft.next_fast_len(t + p - 1)
    rep = np.conj(sfft.fft(replica, nfft))[None, :]
    out = np.empty(signals.shape, np.complex64)
    for a in range(0, signals.shape[0], ROW_BLOCK):
        spec = sfft.fft(signals[a : a + ROW_BLOCK], nfft, axis=-1) * rep
        out[a : a + ROW_BLOCK] = sfft.ifft(spec, axis=-1)[:, :t]
    return out


def matched_filter(survey: Survey, signals: np.ndarray | None = None) -> np.ndarray:
    """Matched filter: correlation with the analytic pulse replica, on the ping's time axis.

    For real or analytic passband data the result is the analytic signal of the real
    cross-correlation ``Σ_m s[k+m] p[m]``; an echo ``A p(t - τ)`` gives a peak of magnitude
    ``≈ A Σ p²`` at sample ``(τ - t0) fs``. Baseband data are correlated with the basebanded
    replica, which gives the baseband version of the same result.

    Args:
        survey: the survey (pulse, fs, signal kind, t0).
        signals: optional (N, T) samples to filter instead of ``survey.samples`` (same kind).
    Returns:
        (N, T) complex64, same kind (passband analytic or baseband) as the input.
    """
    if signals is None:
        if survey.samples is None:
            raise ShsasError("survey samples were not loaded (read the survey with load_samples=True)")
        signals = survey.samples
    s = np.asarray(signals)
    rep = replica_in_frame(survey)
    if not np.iscomplexobj(s):
        # Real data correlated with the analytic replica: exactly the analytic version of the
        # real correlation (its real part is Σ s[k+m] p[m]), with no finite-window Hilbert error.
        return correlate(s, rep)
    # corr(s_a, p_a) = 2 · analytic(corr(s, p)): halve so real and analytic input agree.
    return (0.5 * correlate(s, rep)).astype(np.complex64)


def crop_to_scene(
    survey: Survey,
    signals: np.ndarray | None = None,
    *,
    margin_s: float | None = None,
    box: SceneBox | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Keep only the samples whose time of flight can reach the scene box.

    Each ping keeps the window ``[r_min/c - margin, r_max/c + margin]``; all pings keep the
    same number of samples (the longest window, at most T) so the result stays one (N, T')
    array; a window that would run past either end of the record is moved inside it.

    Args:
        survey: geometry, ``t0``, ``fs``, ``c`` and scene box.
        signals: (N, T) processed signals on the survey's time axis (default: the samples).
        margin_s: extra time on each side, s (default: 4 samples).
        box: region to keep (default: ``survey.meta.scene_box``).
    Returns:
        (cropped (N, T') same dtype, new t0 (N,) float64 s) with ``t0_new[n] = t0[n] + k_n / fs``.
    """
    sig = survey.samples if signals is None else np.asarray(signals)
    if sig is None:
        raise ShsasError("survey samples were not loaded")
    t = sig.shape[1]
    fs, c = survey.meta.fs, survey.meta.sound_speed
    margin = 4.0 / fs if margin_s is None else float(margin_s)
    r_min, r_max = two_way_range_bounds(survey.tx, survey.rx, box or survey.meta.scene_box)
    start = np.floor((r_min / c - margin - survey.t0) * fs).astype(np.int64)
    stop = np.ceil((r_max / c + margin - survey.t0) * fs).astype(np.int64) + 1
    start = np.clip(start, 0, t - 1)
    stop = np.clip(stop, start + 1, t)
    length = int((stop - start).max())
    # Shift windows that would run past the record back so every ping keeps `length` samples.
    start = np.clip(start, 0, max(t - length, 0))
    length = min(length, t)
    idx = start[:, None] + np.arange(length)[None, :]
    out = np.take_along_axis(sig, idx, axis=1)
    return out, survey.t0 + start / fs
