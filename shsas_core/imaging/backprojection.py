"""Time-domain backprojection of complex ping signals onto voxels or arbitrary points.

``I(x) = Σ_n b_n(x) · s_n(t_n(x)) [· exp(j 2π f_c t_n(x))]`` with the two-way time of flight
``t_n(x) = (|x - tx_n| + |x - rx_n|) / c``, ``s_n`` read at fractional sample
``(t_n(x) - t0_n) fs`` by linear (or nearest) interpolation, zero outside the record, the phase
term only for basebanded signals (``carrier_hz`` given) and ``b_n`` an optional TX/RX beam-cone
mask.

The work is a sum over (voxel, ping) pairs done block by block: voxels in blocks of
``voxel_block`` and pings in chunks of ``ping_chunk``, so memory stays bounded (signals of one
chunk + one block of voxels) whatever the survey and grid sizes. The block kernel is plain torch
code; it runs eagerly or through ``torch.compile`` (inductor: C++/OpenMP on CPU, Triton on CUDA),
which fuses distance, gather, interpolation and the ping sum into one loop without the
(voxels x pings) temporaries of the eager version.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, no_progress
from shsas_core.data.survey import SceneBox, Survey
from shsas_core.data.volume import Grid, Volume

log = logging.getLogger(__name__)


class BackprojectionConfig(BaseModel):
    """Settings of :func:`backproject`. Defaults run on a 2-core CPU."""

    model_config = ConfigDict(extra="forbid")

    interpolation: Literal["linear", "nearest"] = Field(
        "linear", description="sub-sample interpolation (nearest = nearest-lower sample)")
    upsample: int = Field(1, ge=1, le=32, description="FFT upsampling factor applied first")
    demodulate: bool = Field(
        True, description="baseband passband signals at the pulse centre before interpolating and "
        "restore the phase per voxel: far more accurate linear interpolation at low fs/f_c")
    use_beams: bool = Field(True, description="apply TX/RX beam cones when the survey has them")
    crop: bool = Field(True, description="drop samples outside the grid's range window first")
    voxel_block: int | None = Field(
        None, ge=1, le=1 << 24, description="voxels per kernel call (None: 16384, or 262144 for "
        "the compiled kernel on CUDA)")
    ping_chunk: int | None = Field(
        None, ge=1, le=1 << 20, description="pings per kernel call (None: 256, or 1024 for the "
        "compiled kernel on CUDA)")

    def blocks(self, device: torch.device, backend: str) -> tuple[int, int]:
        """(voxel_block, ping_chunk) for a device and a resolved backend (not "auto"). The
        compiled and Triton kernels hold no (voxels x pings) temporaries, so on a GPU they take
        large blocks (fewer launches; the Triton kernel keeps its sums in registers, so one block
        can hold a whole AirSAS grid); the eager kernel materialises ~30 of them and keeps
        CPU-sized blocks everywhere (about 0.5 GB)."""
        if backend == "triton":
            return self.voxel_block or (1 << 22), self.ping_chunk or 4096
        big = backend == "compiled" and device.type == "cuda"
        return (self.voxel_block or (262_144 if big else 16_384),
                self.ping_chunk or (1024 if big else 256))

    backend: Literal["auto", "compiled", "eager", "triton"] = Field(
        "auto", description="compiled = torch.compile kernel; triton = the hand-written Triton "
        "kernel (CUDA only); auto takes triton on CUDA when Triton imports, else compiles for "
        "large problems (>= 5e7 voxel-pings) and falls back to eager if compilation is unavailable")


@dataclasses.dataclass(frozen=True)
class Beams:
    """Beam cones: a (voxel, ping) pair counts only inside both cones.

    Attributes:
        tx_dir, rx_dir: (N, 3) pointing vectors (normalised here), or None for no cone.
        tx_half_angle, rx_half_angle: half of the full cone angle, radians.
    """

    tx_dir: np.ndarray | None
    rx_dir: np.ndarray | None
    tx_half_angle: float = math.pi
    rx_half_angle: float = math.pi

    @classmethod
    def from_survey(cls, survey: Survey) -> Beams | None:
        m = survey.meta
        tx = survey.tx_dir if (m.tx_beamwidth_deg and survey.tx_dir is not None) else None
        rx = survey.rx_dir if (m.rx_beamwidth_deg and survey.rx_dir is not None) else None
        if tx is None and rx is None:
            return None
        return cls(tx, rx, math.radians((m.tx_beamwidth_deg or 360.0) / 2),
                   math.radians((m.rx_beamwidth_deg or 360.0) / 2))


# ------------------------------------------------------------------------------------------
# the block kernel


def _bp_block(
    px: torch.Tensor,
    py: torch.Tensor,
    pz: torch.Tensor,
    tx: torch.Tensor,
    rx: torch.Tensor,
    a: torch.Tensor,
    sig: torch.Tensor,
    k: torch.Tensor,
    phase_k: torch.Tensor,
    txd: torch.Tensor,
    rxd: torch.Tensor,
    nearest: bool,
    with_phase: bool,
    with_beams: bool,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum over one chunk of pings for one block of voxels.

    Layouts are chosen for the compiled loop: coordinates as separate contiguous vectors (one
    vector load per coordinate instead of strided gathers), per-ping values as rows of (4, N)
    tables, the signals as one flat float array with re/im interleaved so a linear
    interpolation reads 4 neighbouring floats, and int32 sample indices.

    Args:
        px, py, pz: (V,) float32 voxel coordinates, m (relative to a local origin).
        tx, rx: (3, N) float32 sensor positions in the same frame.
        a: (N,) float32 sample index of time 0: ``t0 · fs`` (so the index is ``d·k - a``).
        sig: (N·(T+1)·2,) float32 flat signals, re/im interleaved, one zero sample appended.
        k: () ``fs / c`` samples per metre of two-way path.
        phase_k: () ``2π f_c / c`` rad per metre (used when ``with_phase``).
        txd, rxd: (4, N) unit pointing vector and cos(half angle) (used when ``with_beams``).
    Returns:
        (V,) real and imaginary sums.
    """
    n = a.shape[0]
    t1 = sig.shape[0] // (2 * n)
    t = t1 - 1
    x, y, z = px[:, None], py[:, None], pz[:, None]
    ex, ey, ez = x - tx[0], y - tx[1], z - tx[2]
    fx, fy, fz = x - rx[0], y - rx[1], z - rx[2]
    dt = torch.sqrt(ex * ex + ey * ey + ez * ez)  # (V, N), fused away when compiled
    dr = torch.sqrt(fx * fx + fy * fy + fz * fz)
    d = dt + dr
    idx = d * k - a
    valid = (idx >= 0) & (idx <= t - 1)
    if with_beams:
        ct = ex * txd[0] + ey * txd[1] + ez * txd[2]
        cr = fx * rxd[0] + fy * rxd[1] + fz * rxd[2]
        valid = valid & (ct >= txd[3] * dt) & (cr >= rxd[3] * dr)
    fl = torch.floor(idx).clamp(0, t - 1)
    base = (fl.to(torch.int32) + torch.arange(n, dtype=torch.int32, device=a.device) * t1) * 2
    # Indices are clamped into range above, so the unchecked gather is safe (and lets the
    # compiler drop the bounds checks and negative-index wrapping of ordinary indexing).
    gather = torch.ops.aten._unsafe_index
    re = gather(sig, [base])
    im = gather(sig, [base + 1])
    if not nearest:
        w = idx - fl
        re = re + w * (gather(sig, [base + 2]) - re)
        im = im + w * (gather(sig, [base + 3]) - im)
    zero = torch.zeros((), dtype=re.dtype, device=re.device)
    re = torch.where(valid, re, zero)
    im = torch.where(valid, im, zero)
    if with_phase:
        ph = d * phase_k
        c, s = torch.cos(ph), torch.sin(ph)
        re, im = re * c - im * s, re * s + im * c
    return re.sum(1), im.sum(1)


_COMPILED: dict[str, object] = {}

#: With backend "auto", problems below this many voxel-pings run eagerly: compilation takes
#: ~10-30 s on a 2-core CPU (a few s with a warm inductor cache), won back above ~5e7.
AUTO_COMPILE_MIN_WORK = 50_000_000


def resolve_backend(backend: str, device: torch.device, work: int) -> str:
    """The kernel a call runs: "triton", "eager", "compiled", or "auto" (compiled, falling back
    to eager if compilation fails). ``work`` = voxels x pings."""
    if backend == "triton" or (backend == "auto" and device.type == "cuda"):
        from shsas_core.imaging import _backprojection_triton as backprojection_triton

        if device.type == "cuda" and backprojection_triton.available():
            return "triton"
        if backend == "triton":
            raise ShsasError("backprojection backend 'triton' needs a CUDA device and Triton "
                             f"(device {device}, Triton importable: {backprojection_triton.available()})")
    if backend == "auto" and work < AUTO_COMPILE_MIN_WORK:
        return "eager"  # compiling costs seconds; small problems finish sooner eagerly
    return backend


def _kernel(backend: str, device: torch.device):
    """The block kernel: ``torch.compile``-d once per process and device type, or eager.

    ``torch.compile`` compiles lazily at the first call, so a failure (no C++ compiler, no
    Triton) surfaces there; with ``backend="auto"`` the returned callable then falls back to
    the eager kernel for the rest of the process, with a warning.
    """
    if backend == "eager":
        return _bp_block
    if backend == "triton":
        from shsas_core.imaging._backprojection_triton import bp_block

        return bp_block
    key = device.type
    if key not in _COMPILED:
        _COMPILED[key] = torch.compile(_bp_block, dynamic=False, fullgraph=True)
    compiled = _COMPILED[key]
    if backend == "compiled":
        return compiled

    def guarded(*args):
        fn = _COMPILED[key]
        if fn is _bp_block:
            return _bp_block(*args)
        try:
            return fn(*args)
        except Exception as exc:  # compiler toolchain missing or unsupported platform
            log.warning("torch.compile failed (%s); using the eager backprojection kernel",
                        str(exc).splitlines()[0][:200])
            _COMPILED[key] = _bp_block
            return _bp_block(*args)

    return guarded


# ------------------------------------------------------------------------------------------
# public API


def upsample_signals(signals: torch.Tensor, factor: int) -> torch.Tensor:
    """FFT (band-limited) upsampling of complex signals along the last axis.

    Args:
        signals: (N, T) complex.
        factor: integer factor U >= 1.
    Returns:
        (N, T·U) complex at rate ``U · fs``; sample ``U·k`` equals input sample ``k``.
    """
    if factor == 1:
        return signals
    n, t = signals.shape
    spec = torch.fft.fft(signals, dim=-1)
    out = torch.zeros((n, t * factor), dtype=spec.dtype, device=spec.device)
    h = (t + 1) // 2  # non-negative frequencies 0..h-1, negative ones after
    out[:, :h] = spec[:, :h]
    out[:, t * factor - (t - h) :] = spec[:, h:]
    if t % 2 == 0:  # split the Nyquist bin so a real signal stays real
        out[:, h] = 0.5 * spec[:, h]
        out[:, t * factor - (t - h)] = 0.5 * spec[:, h]
    return torch.fft.ifft(out, dim=-1) * factor


def backproject(
    signals: np.ndarray | torch.Tensor,
    tx: np.ndarray,
    rx: np.ndarray,
    t0: np.ndarray,
    fs: float,
    c: float,
    points: np.ndarray,
    *,
    carrier_hz: float | None = None,
    beams: Beams | None = None,
    config: BackprojectionConfig | None = None,
    device: torch.device | str = "cpu",
    progress: ProgressFn = no_progress,
    should_stop: StopFn | None = None,
) -> np.ndarray:
    """Backproject complex ping signals onto points.

    Args:
        signals: (N, T) complex samples at ``t0[n] + k / fs``: analytic passband, or baseband
            (``exp(-j2π f_c t)`` removed, ``t`` absolute) when ``carrier_hz`` is given.
        tx, rx: (N, 3) sensor positions, m.
        t0: (N,) time of the first sample, s.
        fs: sample rate, Hz. c: sound speed, m/s.
        points: (V, 3) positions, m.
        carrier_hz: carrier of basebanded signals (adds the phase term), None for passband.
        beams: optional beam cones.
        config: interpolation, upsampling, block sizes, backend.
        device: torch device ("cpu", "cuda", ...).
    Returns:
        (V,) complex64 image values.
    """
    cfg = config or BackprojectionConfig()
    dev = torch.device(device)
    sig = torch.as_tensor(np.asarray(signals) if not torch.is_tensor(signals) else signals)
    if sig.ndim != 2 or not sig.is_complex():
        raise ShsasError(f"backprojection: signals must be (N, T) complex, got {tuple(sig.shape)} {sig.dtype}")
    n = sig.shape[0]
    tx, rx, t0 = (np.asarray(v, dtype=np.float64) for v in (tx, rx, t0))
    points = np.asarray(points, dtype=np.float64)
    if tx.shape != (n, 3) or rx.shape != (n, 3) or t0.shape != (n,):
        raise ShsasError(f"backprojection: tx/rx must be ({n}, 3) and t0 ({n},), got "
                         f"{tx.shape}, {rx.shape}, {t0.shape}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise ShsasError(f"backprojection: points must be (V, 3), got {points.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(tx)) and np.all(np.isfinite(rx))):
        raise ShsasError("backprojection: non-finite positions")
    if fs <= 0 or c <= 0:
        raise ShsasError(f"backprojection: fs and c must be > 0 (got {fs}, {c})")
    v_total = len(points)
    if v_total == 0:
        return np.zeros(0, np.complex64)

    # A local origin keeps float32 distances accurate for surveys far from the frame origin.
    origin = points.mean(0)
    up = cfg.upsample
    fs_u = fs * up
    backend = resolve_backend(cfg.backend, dev, v_total * n)
    kernel = _kernel(backend, dev)
    nearest = cfg.interpolation == "nearest"
    with_phase = carrier_hz is not None
    with_beams = beams is not None
    f32 = dict(dtype=torch.float32, device=dev)

    def beam_rows(d: np.ndarray | None, half: float) -> np.ndarray:
        out = np.zeros((n, 4))
        if d is None:
            out[:, 3] = -2.0  # cos >= -2 always holds: no cone
        else:
            out[:, :3] = d / np.linalg.norm(d, axis=1, keepdims=True)
            out[:, 3] = math.cos(min(half, math.pi))
        return out

    txd_all = beam_rows(beams.tx_dir if beams else None, beams.tx_half_angle if beams else math.pi)
    rxd_all = beam_rows(beams.rx_dir if beams else None, beams.rx_half_angle if beams else math.pi)
    k = torch.tensor(fs_u / c, **f32)
    phase_k = torch.tensor(2 * math.pi * (carrier_hz or 0.0) / c, **f32)

    vb, pcs = cfg.blocks(dev, "compiled" if backend == "auto" else backend)
    nb = min(vb, v_total)
    pc = min(pcs, n)
    # float64 accumulators on the device: no host sync per block, no float32 drift over
    # tens of thousands of pings
    acc_re = torch.zeros(v_total, dtype=torch.float64, device=dev)
    acc_im = torch.zeros(v_total, dtype=torch.float64, device=dev)
    chunks = [(a, min(a + pc, n)) for a in range(0, n, pc)]
    total_steps = len(chunks) * math.ceil(v_total / nb)
    step = 0
    # Points padded to whole blocks so every kernel call has the same shape (one compilation).
    v_pad = math.ceil(v_total / nb) * nb
    pts_np = np.zeros((3, v_pad))
    pts_np[:, :v_total] = (points - origin).T
    pts_all = torch.as_tensor(pts_np, **f32)
    for a, b in chunks:
        check_stop(should_stop)
        m = b - a
        s = upsample_signals(sig[a:b].to(device=dev, dtype=torch.complex64), up)
        tu = s.shape[1]
        # Pings padded to the chunk size with zero signals, for the same reason.
        buf = torch.zeros((pc, tu + 1, 2), **f32)
        buf[:m, :tu] = torch.view_as_real(s)
        tab = np.zeros((4 + 4 + 4 + 4 + 1, pc))
        tab[0:3, :m] = (tx[a:b] - origin).T
        tab[4:7, :m] = (rx[a:b] - origin).T
        tab[8:12, :] = txd_all[:1].T  # padding pings: any valid row (their signal is zero)
        tab[12:16, :] = rxd_all[:1].T
        tab[8:12, :m] = txd_all[a:b].T
        tab[12:16, :m] = rxd_all[a:b].T
        tab[16, :m] = t0[a:b] * fs_u
        tab_t = torch.as_tensor(tab, **f32)
        tx_t, rx_t = tab_t[0:3].contiguous(), tab_t[4:7].contiguous()
        txd_t, rxd_t = tab_t[8:12].contiguous(), tab_t[12:16].contiguous()
        a_t = tab_t[16].contiguous()
        flat = buf.reshape(-1)
        if backend in ("compiled", "auto"):
            # The record length is the one size that differs between surveys; compiled for one
            # length only, a long-lived worker would recompile per survey and, past dynamo's
            # recompile limit, lose the compiled kernel for the rest of the process.
            torch._dynamo.mark_dynamic(flat, 0)
        for v0 in range(0, v_total, nb):
            v1 = min(v0 + nb, v_total)
            p = pts_all[:, v0 : v0 + nb]
            re, im = kernel(p[0], p[1], p[2], tx_t, rx_t, a_t, flat, k, phase_k, txd_t, rxd_t,
                            nearest, with_phase, with_beams)
            acc_re[v0:v1] += re[: v1 - v0]
            acc_im[v0:v1] += im[: v1 - v0]
            step += 1
            progress(step / total_steps, "backprojection", {})
    return torch.complex(acc_re, acc_im).cpu().numpy().astype(np.complex64)


def default_signals(survey: Survey) -> tuple[np.ndarray, str]:
    """Signals to image when none are given (:func:`~shsas_core.signal.sources.signals_for`'s
    ``stored`` when the survey has them, else ``matched``).

    Returns ((N, T) complex, "deconvolved" or "matched").
    """
    from shsas_core.signal.sources import has_stored, signals_for

    if has_stored(survey):
        return signals_for(survey, "stored").values, "deconvolved"
    return signals_for(survey, "matched").values, "matched"


def backproject_survey(
    survey: Survey,
    grid: Grid,
    signals: np.ndarray | None = None,
    *,
    config: BackprojectionConfig | None = None,
    device: torch.device | str = "cpu",
    progress: ProgressFn = no_progress,
    should_stop: StopFn | None = None,
) -> Volume:
    """Backproject a survey onto a voxel grid.

    Args:
        survey: geometry, t0, fs, sound speed, signal kind, beams.
        grid: voxel grid (usually ``Grid.over(survey.meta.scene_box, 64)``).
        signals: (N, T) complex on the survey's time axis, same frame as the survey (analytic
            passband, or baseband for baseband surveys); default :func:`default_signals`.
        config: see :class:`BackprojectionConfig`.
    Returns:
        complex64 :class:`Volume` named "backprojection".
    """
    from shsas_core.signal.chain import baseband, crop_to_scene

    cfg = config or BackprojectionConfig()
    if signals is None:
        signals, _ = default_signals(survey)
    signals = np.asarray(signals)
    if not np.iscomplexobj(signals):
        raise ShsasError("backprojection: signals must be complex (analytic or baseband)")
    if signals.shape != survey.shape:
        raise ShsasError(f"backprojection: signals shape {signals.shape} != survey shape {survey.shape}")
    t0 = survey.t0
    if cfg.crop:
        box = SceneBox(min=grid.box_min, max=grid.box_max)
        signals, t0 = crop_to_scene(survey, signals, box=box, margin_s=8.0 / survey.meta.fs)
    carrier = None
    if survey.meta.signal_kind == "baseband":
        carrier = float(survey.meta.carrier_hz)
    elif cfg.demodulate:
        carrier = survey.meta.pulse.f_center
        signals = baseband(signals, t0, survey.meta.fs, carrier)
    beams = Beams.from_survey(survey) if cfg.use_beams else None
    values = backproject(signals, survey.tx, survey.rx, t0, survey.meta.fs, survey.meta.sound_speed,
                         grid.points(), carrier_hz=carrier, beams=beams, config=cfg, device=device,
                         progress=progress, should_stop=should_stop)
    return Volume(grid, values.reshape(grid.shape), name="backprojection")
