"""Exact synthetic echoes for signal, deconvolution and backprojection tests.

An echo of a point scatterer is the transmitted pulse delayed by the two-way time of flight,
``A p(t - τ)``, sampled at ``t0 + k / fs``. Fractional delays are applied in the frequency
domain (band-limited interpolation), so the only approximation is the pulse's tiny energy above
fs/2 — independent of everything the tests check.
"""

from __future__ import annotations

import numpy as np


def delayed_pulse(pulse: np.ndarray, delays: np.ndarray, amps: np.ndarray, t0: float, t: int,
                  fs: float) -> np.ndarray:
    """(T,) float64 sum of ``amps[i] * pulse(t - delays[i])`` on ``t0 + k / fs``.

    A complex amplitude ``a`` gives ``Re(a · p_a(t - τ))`` (p_a the analytic pulse): a scatterer
    with a phase shift.
    """
    nfft = 1 << int(np.ceil(np.log2(2 * (t + pulse.size))))
    spec = np.fft.rfft(pulse, nfft)
    f = np.fft.rfftfreq(nfft, 1.0 / fs)
    shift = np.zeros_like(spec, dtype=complex)
    for d, a in zip(np.atleast_1d(delays), np.atleast_1d(amps), strict=True):
        shift += a * np.exp(-2j * np.pi * f * (d - t0))
    return np.fft.irfft(spec * shift, nfft)[:t]


def point_echoes(pulse: np.ndarray, tx: np.ndarray, rx: np.ndarray, t0: np.ndarray, t: int,
                 fs: float, c: float, targets: np.ndarray, amps: np.ndarray | None = None) -> np.ndarray:
    """(N, T) float32 real echoes of point ``targets`` (K, 3) seen by pings (tx, rx) (N, 3).

    ``amps`` (K,) real or complex scattering amplitudes (default 1)."""
    targets = np.atleast_2d(targets)
    amps = np.ones(len(targets)) if amps is None else np.asarray(amps)
    out = np.zeros((len(tx), t))
    for n in range(len(tx)):
        r = np.linalg.norm(targets - tx[n], axis=1) + np.linalg.norm(targets - rx[n], axis=1)
        out[n] = delayed_pulse(pulse, r / c, amps, t0[n], t, fs)
    return out.astype(np.float32)


def peak_sidelobe_db(y: np.ndarray) -> float:
    """Peak sidelobe level of a single-peak response, dB: highest value outside the main lobe
    (bounded by the first local minima either side of the peak) relative to the peak."""
    a = np.abs(np.ravel(y))
    i = int(np.argmax(a))
    lo = i
    while lo > 0 and a[lo - 1] < a[lo]:
        lo -= 1
    hi = i
    while hi < a.size - 1 and a[hi + 1] < a[hi]:
        hi += 1
    side = np.concatenate([a[:lo], a[hi + 1 :]])
    return float(20 * np.log10(side.max() / a[i]))
