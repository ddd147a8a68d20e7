"""Fast images for search loops: backprojection with the signals prepared once.

Autofocus and the focus-height search image the same survey hundreds of times with slightly
different geometry (sound speed, time offset, sensor positions, image plane). The expensive
preparation (deconvolution, basebanding at the pulse centre) does not depend on those, so
:class:`QuickImager` does it once and each :meth:`QuickImager.image` call is one call of the
project's :func:`~shsas_core.backprojection.backproject` on a small grid.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .backprojection import Beams, backproject
from .survey import Survey


@dataclasses.dataclass(frozen=True)
class Geometry:
    """What a search may change: sensor positions, first-sample times, sound speed."""

    tx: np.ndarray
    rx: np.ndarray
    t0: np.ndarray
    sound_speed: float


class QuickImager:
    """Backproject one survey's (deconvolved) signals onto arbitrary points, many times.

    Args:
        survey: the survey (geometry, fs, signal kind).
        signals: (N, T) complex signals on the survey's time axis (e.g. ``deconvolve(survey)``).
        pings: which pings to use (default all): a subset makes each image cheaper.
    """

    def __init__(self, survey: Survey, signals: np.ndarray, pings: np.ndarray | None = None):
        from .signal import baseband

        idx = np.arange(survey.num_pings) if pings is None else np.asarray(pings)
        sig = np.asarray(signals)[idx]
        self.fs = survey.meta.fs
        self.pings = idx
        if survey.meta.signal_kind == "baseband":
            self.carrier = float(survey.meta.carrier_hz)  # type: ignore[arg-type]
            self.signals = sig.astype(np.complex64)
        else:
            # basebanded at the pulse centre once, with the nominal t0 (the phase reference is
            # absolute time, so a later t0 change is a pure shift of the sample axis)
            self.carrier = survey.meta.pulse.f_center
            self.signals = baseband(sig, survey.t0[idx], self.fs, self.carrier).astype(np.complex64)
        self.t0_nominal = survey.t0[idx]
        self.beams = Beams.from_survey(survey.subset(idx))

    def image(self, geometry: Geometry, points: np.ndarray) -> np.ndarray:
        """(V,) complex image at ``points`` for ``geometry`` (arrays over the imager's pings).

        A ``t0`` other than the nominal one moves the samples in time; their baseband phase
        was removed at the nominal times, so it is put back for the shift.
        """
        sig = self.signals
        dt = geometry.t0 - self.t0_nominal
        if np.any(dt != 0):
            # s_b(t) = s_a(t) e^{-j2πf t}: the same samples at times t + dt carry e^{-j2πf dt} more
            sig = (sig * np.exp(-2j * np.pi * self.carrier * dt)[:, None]).astype(np.complex64)
        return backproject(sig, geometry.tx, geometry.rx, geometry.t0, self.fs, geometry.sound_speed,
                           points, carrier_hz=self.carrier, beams=self.beams)
