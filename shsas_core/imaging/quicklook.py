"""Fast images for search loops: backprojection with the signals prepared once.

Autofocus and the focus-height search image the same survey hundreds of times with slightly
different geometry (sound speed, time offset, sensor positions, image plane). The expensive
preparation (deconvolution, basebanding at the pulse centre) does not depend on those, so
:class:`QuickImager` does it once and each :meth:`QuickImager.image` call is one call of the
project's :func:`~shsas_core.imaging.backprojection.backproject` on a small grid.

The calls run the compiled kernel (``torch.compile``; benchmarks/bench_autofocus.py): one search
makes hundreds of small images, so the one-off compilation (seconds, cached on disk between
processes) is won back many times over, where the backprojection's own "auto" rule, which
looks at one call only, would stay eager. Every call has the same block shapes (pings padded to
whole chunks with silent pings), so the kernel compiles once per image size. Where compilation
is unavailable the eager kernel takes over, with a warning.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from shsas_core.data.survey import Survey
from shsas_core.imaging.backprojection import BackprojectionConfig, Beams, backproject

log = logging.getLogger(__name__)

#: Pings per kernel call; the imager pads its pings to a whole number of these.
PING_CHUNK = 128
#: Points per kernel call (a 48 x 48 search plane is one block).
VOXEL_BLOCK = 4096
_COMPILED = BackprojectionConfig(backend="compiled", voxel_block=VOXEL_BLOCK, ping_chunk=PING_CHUNK)
_EAGER = BackprojectionConfig(backend="eager", voxel_block=VOXEL_BLOCK, ping_chunk=PING_CHUNK)
#: Set once compilation has failed in this process: later imagers go straight to eager.
_compile_failed = False


@dataclasses.dataclass(frozen=True)
class Geometry:
    """What a search may change: sensor positions, first-sample times, sound speed."""

    tx: np.ndarray
    rx: np.ndarray
    t0: np.ndarray
    sound_speed: float


def _pad_rows(a: np.ndarray | None, pad: int) -> np.ndarray | None:
    """``a`` with its first row repeated ``pad`` times at the end (rows of silent pings)."""
    if a is None or pad == 0:
        return a
    return np.concatenate([a, np.repeat(a[:1], pad, axis=0)])


class QuickImager:
    """Backproject one survey's (deconvolved) signals onto arbitrary points, many times.

    Args:
        survey: the survey (geometry, fs, signal kind).
        signals: (N, T) complex signals on the survey's time axis (e.g. ``deconvolve(survey)``).
        pings: which pings to use (default all): a subset makes each image cheaper.
        compiled: run the compiled kernel (default); False: the eager one.
    """

    def __init__(self, survey: Survey, signals: np.ndarray, pings: np.ndarray | None = None,
                 compiled: bool = True):
        from shsas_core.signal.chain import baseband

        idx = np.arange(survey.num_pings) if pings is None else np.asarray(pings)
        sig = np.asarray(signals)[idx]
        self.fs = survey.meta.fs
        self.pings = idx
        if survey.meta.signal_kind == "baseband":
            self.carrier = float(survey.meta.carrier_hz)  # type: ignore[arg-type]
            sig = sig.astype(np.complex64)
        else:
            # basebanded at the pulse centre once, with the nominal t0 (the phase reference is
            # absolute time, so a later t0 change is a pure shift of the sample axis)
            self.carrier = survey.meta.pulse.f_center
            sig = baseband(sig, survey.t0[idx], self.fs, self.carrier).astype(np.complex64)
        self.pad = (-len(idx)) % PING_CHUNK
        self.signals = np.concatenate([sig, np.zeros((self.pad, sig.shape[1]), np.complex64)])
        self.t0_nominal = survey.t0[idx]
        beams = Beams.from_survey(survey.subset(idx))
        self.beams = None if beams is None else dataclasses.replace(
            beams, tx_dir=_pad_rows(beams.tx_dir, self.pad), rx_dir=_pad_rows(beams.rx_dir, self.pad))
        self.compiled = compiled

    def image(self, geometry: Geometry, points: np.ndarray) -> np.ndarray:
        """(V,) complex image at ``points`` for ``geometry`` (arrays over the imager's pings).

        A ``t0`` other than the nominal one moves the samples in time; their baseband phase
        was removed at the nominal times, so it is put back for the shift.
        """
        global _compile_failed

        sig = self.signals
        dt = geometry.t0 - self.t0_nominal
        if np.any(dt != 0):
            # s_b(t) = s_a(t) e^{-j2πf t}: the same samples at times t + dt carry e^{-j2πf dt} more
            ph = np.concatenate([np.exp(-2j * np.pi * self.carrier * dt), np.ones(self.pad)])
            sig = (sig * ph[:, None]).astype(np.complex64)
        tx, rx, t0 = (_pad_rows(np.asarray(a, dtype=np.float64), self.pad)
                      for a in (geometry.tx, geometry.rx, geometry.t0))
        args = (sig, tx, rx, t0, self.fs, geometry.sound_speed, points)
        kw = {"carrier_hz": self.carrier, "beams": self.beams}
        if self.compiled and not _compile_failed:
            try:
                return backproject(*args, **kw, config=_COMPILED)
            except Exception as exc:  # no C++ toolchain, unsupported platform
                # only the compiler can fail here: the eager call below re-raises any input error
                log.warning("quicklook: torch.compile failed (%s); search images run eagerly",
                            str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__)
                _compile_failed = True
        return backproject(*args, **kw, config=_EAGER)
