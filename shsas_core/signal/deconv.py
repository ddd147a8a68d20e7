"""Pulse deconvolution: turn each ping into a temporally compact signal ``s_PD`` (paper §3.1).

Measurement model (analytic signals, the conventions of :mod:`shsas_core.signal.chain`):
``s_a = s_PD ⊛ p_a`` (linear convolution), with ``p_a`` the analytic pulse replica starting at
t = 0. So an echo ``A p(t - τ)`` corresponds to ``s_PD = A δ(t - τ)``: deconvolved peaks sit at
the true delays on the survey's own time axis.

Methods:

* ``wiener`` (default, fast, closed form): ``S_PD = S_a P_a* / (|P_a|² + ε max|P_a|²) · W(f)``
  with ``W`` a taper over the pulse band (Taylor by default: −34 dB peak sidelobes where the
  LFM matched filter has about −14 dB). Normalised so an impulse of amplitude A gives a peak
  of about A.
* ``neural``: the implicit network of Reed et al. (see :mod:`shsas_core.signal.deconv_neural`).
* ``none``: the analytic signal itself (no deconvolution).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import scipy.fft as sfft
import torch
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import windows

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, no_progress
from shsas_core.data.survey import Survey
from shsas_core.signal.chain import analytic_samples, replica_in_frame, row_block


class NeuralDeconvConfig(BaseModel):
    """Settings of the neural deconvolution network and its fit.

    Defaults are CPU-friendly; the public code of the paper used 1000 Adam steps at lr 1e-3 per
    batch of 360 pings, 16 levels and 2^19-row tables (λ1 = 0.1, λ2 = 1e-4 as here).
    """

    model_config = ConfigDict(extra="forbid")

    steps: int = Field(300, ge=1, le=100_000, description="Adam steps per batch of pings")
    lr: float = Field(3e-3, gt=0, le=1.0, description="Adam learning rate (1e-2 can kill the ReLUs)")
    pings_per_batch: int = Field(64, ge=1, le=100_000)
    lambda_sparsity: float = Field(0.1, ge=0, description="λ1: weight of the L1 sparsity term")
    lambda_phase: float = Field(1e-4, ge=0, description="λ2: weight of the L1 phase-gradient term")
    levels: int = Field(8, ge=1, le=24, description="hash-encoding levels")
    features_per_level: int = Field(2, ge=1, le=8)
    log2_table_size: int = Field(16, ge=8, le=24, description="hash table entries per level = 2^this")
    base_resolution: int = Field(16, ge=2, le=4096, description="coarsest grid cells along time")
    project_to_band: bool = Field(
        True, description="filter the fitted s_PD to the pulse band with the Wiener taper: the "
        "data constrain only that band, and on a simulated sphere ~90 % of the raw output's "
        "energy lay below it (a smooth envelope the data cannot correct), which blurred the "
        "backprojected image; False keeps the raw sparse output")
    hidden: int = Field(32, ge=4, le=512)
    layers: int = Field(2, ge=1, le=8, description="hidden layers of the MLP")
    seed: int = Field(0, ge=0)


class DeconvConfig(BaseModel):
    """How to deconvolve the pulse from the measurements."""

    model_config = ConfigDict(extra="forbid")

    method: Literal["wiener", "neural", "none"] = "wiener"
    # -- wiener
    noise_level: float = Field(1e-2, gt=0, le=10, description="ε, relative to max |P|² (regularises weak bins)")
    taper: Literal["taylor", "hann", "tukey", "rect"] = Field(
        "taylor", description="target band shape: controls sidelobes (rect = narrowest mainlobe)")
    taper_param: float = Field(35.0, ge=0, description="taylor sidelobe level (dB) or tukey ratio")
    # -- neural
    neural: NeuralDeconvConfig = NeuralDeconvConfig()


def _band_taper(n: int, kind: str, param: float) -> np.ndarray:
    if n <= 0:
        return np.zeros(0)
    if kind == "taylor":
        return windows.taylor(n, nbar=4, sll=param or 35.0, norm=True, sym=True)
    if kind == "hann":
        return windows.hann(n, sym=True) if n > 2 else np.ones(n)
    if kind == "tukey":
        return windows.tukey(n, alpha=min(max(param, 0.0), 1.0) if param <= 1 else 0.5, sym=True)
    return np.ones(n)


def signal_band(survey: Survey) -> tuple[float, float]:
    """(low, high) frequency of the pulse band in the frame of the survey's samples, Hz.

    Passband data: the chirp's band. Baseband data: the chirp's band minus the carrier.
    """
    p = survey.meta.pulse
    lo, hi = min(p.f_start, p.f_stop), max(p.f_start, p.f_stop)
    if survey.meta.signal_kind == "baseband":
        fc = float(survey.meta.carrier_hz)
        lo, hi = lo - fc, hi - fc
    return lo, hi


def wiener_deconvolve(
    signals: np.ndarray,
    replica: np.ndarray,
    fs: float,
    band: tuple[float, float],
    *,
    noise_level: float = 1e-2,
    taper: str = "taylor",
    taper_param: float = 35.0,
    chunk: int | None = None,
    should_stop: StopFn | None = None,
) -> np.ndarray:
    """Closed-form Wiener deconvolution of complex signals by a complex replica.

    Args:
        signals: (N, T) complex analytic (or baseband) samples.
        replica: (P,) complex replica in the same frame, starting at lag 0.
        fs: sample rate, Hz.
        band: (low, high) Hz, frequencies kept (in the signals' frame, may be negative).
        noise_level: ε relative to ``max |P|²``.
        taper, taper_param: target band shape (see :class:`DeconvConfig`).
        chunk: pings per FFT batch (bounds memory; default :func:`~shsas_core.signal.chain.row_block`).
        should_stop: polled between batches (:mod:`shsas_core.common.progress`).
    Returns:
        (N, T) complex64 ``s_PD`` on the same time axis; an impulse of amplitude A -> peak ≈ A.
    """
    signals = np.atleast_2d(np.asarray(signals))
    n, t = signals.shape
    nfft = sfft.next_fast_len(t + replica.size - 1)
    p = sfft.fft(replica, nfft)
    f = sfft.fftfreq(nfft, 1.0 / fs)
    inband = (f >= band[0]) & (f <= band[1])
    if not inband.any():
        raise ShsasError(f"deconvolution: pulse band {band} Hz holds no FFT bin at fs={fs:g} Hz")
    # Taper in frequency order (fftfreq order is not sorted for negative frequencies).
    order = np.argsort(f[inband], kind="stable")
    w = np.zeros(nfft)
    idx = np.flatnonzero(inband)[order]
    w[idx] = _band_taper(idx.size, taper, taper_param)
    power = np.abs(p) ** 2
    filt = np.conj(p) / (power + noise_level * power.max()) * w
    # Unit peak for a unit impulse: the response to A δ is A · ifft(|P|²/(|P|²+ε) W)[0].
    gain = float(np.real(np.sum(power / (power + noise_level * power.max()) * w))) / nfft
    filt = filt / gain
    out = np.empty((n, t), dtype=np.complex64)
    chunk = chunk or row_block(nfft)
    for a in range(0, n, chunk):
        check_stop(should_stop)
        spec = sfft.fft(signals[a : a + chunk], nfft, axis=-1)
        out[a : a + chunk] = sfft.ifft(spec * filt[None, :], axis=-1)[:, :t]
    return out


def band_filter(
    signals: np.ndarray,
    fs: float,
    band: tuple[float, float],
    *,
    taper: str = "taylor",
    taper_param: float = 35.0,
    chunk: int | None = None,
    should_stop: StopFn | None = None,
) -> np.ndarray:
    """Zero-phase filter to ``band`` with the Wiener taper (unit gain at the taper's peak).

    Args:
        signals: (N, T) complex. band: (low, high) Hz in the signals' frame.
    Returns:
        (N, T) complex64; an impulse becomes the same pulse shape the Wiener filter produces,
        normalised to a unit peak, centred on the impulse.
    """
    signals = np.atleast_2d(np.asarray(signals))
    n, t = signals.shape
    nfft = sfft.next_fast_len(2 * t)
    f = sfft.fftfreq(nfft, 1.0 / fs)
    inband = (f >= band[0]) & (f <= band[1])
    idx = np.flatnonzero(inband)[np.argsort(f[inband], kind="stable")]
    w = np.zeros(nfft)
    w[idx] = _band_taper(idx.size, taper, taper_param)
    w = w / (w.sum() / nfft)  # unit peak for a unit impulse
    out = np.empty((n, t), dtype=np.complex64)
    chunk = chunk or row_block(nfft)
    for a in range(0, n, chunk):
        check_stop(should_stop)
        out[a : a + chunk] = sfft.ifft(sfft.fft(signals[a : a + chunk], nfft, axis=-1) * w, axis=-1)[:, :t]
    return out


def deconvolve(
    survey: Survey,
    config: DeconvConfig | None = None,
    device: torch.device | str = "cpu",
    progress: ProgressFn = no_progress,
    should_stop: StopFn | None = None,
) -> np.ndarray:
    """Pulse-deconvolved signal ``s_PD`` of every ping.

    Args:
        survey: survey with samples loaded (real, analytic or baseband).
        config: method and parameters (default: Wiener).
        device: torch device for the neural method.
        progress, should_stop: see :mod:`shsas_core.common.progress`.
    Returns:
        (N, T) complex64 on the survey's own time axis (``survey.t0``, ``meta.fs``), analytic
        passband for real/analytic surveys, baseband for baseband surveys.
        A ``meta.pulse_deconvolved`` survey gets its analytic signal whatever ``config`` says.
    """
    config = config or DeconvConfig()
    s = analytic_samples(survey, should_stop)
    check_stop(should_stop)
    # samples deconvolved before import: a second deconvolution would divide the pulse out twice
    if config.method == "none" or survey.meta.pulse_deconvolved:
        progress(1.0, "deconvolution", {})
        return s
    if config.method == "wiener":
        out = np.empty_like(s)
        n = s.shape[0]
        step = 1024
        for a in range(0, n, step):
            check_stop(should_stop)
            out[a : a + step] = wiener_deconvolve(
                s[a : a + step], replica_in_frame(survey), survey.meta.fs, signal_band(survey),
                noise_level=config.noise_level, taper=config.taper, taper_param=config.taper_param,
                should_stop=should_stop)
            progress(min(a + step, n) / n, "deconvolution", {})
        return out
    if config.method == "neural":
        from shsas_core.signal.deconv_neural import neural_deconvolve

        lo, hi = signal_band(survey)
        out = neural_deconvolve(s, replica_in_frame(survey), config.neural, device=device,
                                progress=progress, should_stop=should_stop,
                                band_centre=0.5 * (lo + hi) / survey.meta.fs)
        if config.neural.project_to_band:
            out = band_filter(out, survey.meta.fs, (lo, hi), taper=config.taper,
                              taper_param=config.taper_param, should_stop=should_stop)
        return out
    raise ShsasError(f"deconvolution: unknown method '{config.method}' (use wiener, neural or none)")


#: The point-spread kernel's half width in units of the pulse's resolution time 1/B: the
#: Taylor-tapered Wiener kernel's mainlobe ends at 1.6/B whatever the sample rate and band (the
#: kernel within ±1.6/B holds 99.95 % of its energy at 100 kHz and 250 kHz for a 20 kHz band,
#: and for a 5 kHz band; 8 samples at the default 100 kHz and 20 kHz).
PSF_HALF_WIDTH = 1.6


def psf_half_width(survey: Survey) -> int:
    """The kernel's half width in samples: :data:`PSF_HALF_WIDTH` x ``fs / B``
    (``meta.resolution_samples``), rounded up.

    A width counted in samples would cut the mainlobe wherever samples are denser or the band
    narrower than the default's (at 250 kHz, 8 samples end at 0.67 of the peak)."""
    return max(1, math.ceil(round(PSF_HALF_WIDTH * survey.meta.resolution_samples, 6)))


def point_spread(survey: Survey, config: DeconvConfig | None = None,
                 half_width: int | None = None) -> np.ndarray | None:
    """The deconvolved signal of an ideal point echo: what :func:`deconvolve` makes of a unit
    reflector at a whole-sample delay, as a kernel on the sample grid.

    The replica is placed ``half_width`` samples into an empty record and run through the same
    chain (Wiener filter, or the neural method's band projection, whose target is an impulse), so
    the kernel is the chain's, not a model of it. For baseband surveys the kernel is returned in
    the analytic passband frame the renderer trains in (carrier restored per lag).

    Args:
        survey: pulse, sample rate and signal kind. config: the deconvolution used on the data.
        half_width: ``h``; the kernel has ``2h + 1`` taps (lags -h..h samples); None: the
            mainlobe's, :func:`psf_half_width`.
    Returns:
        (2h + 1,) complex128 with unit value at lag 0 (index h), or None for ``method="none"``
        (the raw echo is a whole chirp, not a compact kernel) and for ``meta.pulse_deconvolved``
        surveys.
    """
    cfg = config or DeconvConfig()
    if cfg.method == "none" or survey.meta.pulse_deconvolved:
        return None  # pre-deconvolved data: their kernel is unknown, the ideal impulse is assumed
    if half_width is None:
        half_width = psf_half_width(survey)
    rep = replica_in_frame(survey)
    # a record as long as the survey's, so the FFT filters are sampled as they are on the data
    n = max(survey.num_samples, rep.size + 4 * half_width + 1)
    at = max(half_width, (n - rep.size) // 2)
    lo, hi = signal_band(survey)
    frame = np.zeros((1, n), np.complex128)
    if cfg.method == "wiener":
        frame[0, at : at + rep.size] = rep[: n - at]
        out = wiener_deconvolve(frame, rep, survey.meta.fs, (lo, hi), noise_level=cfg.noise_level,
                                taper=cfg.taper, taper_param=cfg.taper_param)[0]
    else:  # the neural deconvolution's target is an impulse, projected onto the band
        frame[0, at] = 1.0
        out = band_filter(frame, survey.meta.fs, (lo, hi), taper=cfg.taper, taper_param=cfg.taper_param)[0]
    k = out[at - half_width : at + half_width + 1].astype(np.complex128)
    if not abs(k[half_width]) > 0:
        raise ShsasError("deconvolution: the point-spread kernel is zero at lag 0")
    k = k / k[half_width]
    if survey.meta.signal_kind == "baseband":
        lags = np.arange(-half_width, half_width + 1) / survey.meta.fs
        k = k * np.exp(2j * np.pi * float(survey.meta.carrier_hz) * lags)
    return k
