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
import json
import logging
import math
import os
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from .errors import ShsasError
from .progress import ProgressFn, StopFn, check_stop, no_progress
from .survey import SceneBox, Survey
from .volume import Grid, Volume

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
    voxel_block: int = Field(16384, ge=1, le=1 << 24, description="voxels per kernel call")
    ping_chunk: int = Field(256, ge=1, le=1 << 20, description="pings per kernel call")
    backend: Literal["auto", "compiled", "eager"] = Field(
        "auto", description="compiled = torch.compile kernel; auto falls back to eager if it fails")


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
    pts: torch.Tensor,
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

    Args:
        pts: (V, 3) float32 points, m (relative to a local origin).
        tx, rx: (N, 3) float32 sensor positions in the same frame.
        a: (N,) float32 fractional sample index of time 0 offset: ``t0 · fs``.
        sig: (N, T + 1, 2) float32 signal real/imag with one zero sample appended.
        k: () ``fs / c`` samples per metre of two-way path.
        phase_k: () ``2π f_c / c`` rad per metre (used when ``with_phase``).
        txd, rxd: (N, 4) unit pointing vector and cos(half angle) (used when ``with_beams``).
    Returns:
        (V,) real and imaginary sums.
    """
    n, t1, _ = sig.shape
    t = t1 - 1
    dt = torch.sqrt(((pts[:, None, :] - tx[None, :, :]) ** 2).sum(-1))  # (V, N)
    dr = torch.sqrt(((pts[:, None, :] - rx[None, :, :]) ** 2).sum(-1))
    d = dt + dr
    idx = d * k - a[None, :]
    valid = (idx >= 0) & (idx <= t - 1)
    if with_beams:
        ct = ((pts[:, None, :] - tx[None, :, :]) * txd[None, :, :3]).sum(-1)
        cr = ((pts[:, None, :] - rx[None, :, :]) * rxd[None, :, :3]).sum(-1)
        valid = valid & (ct >= txd[None, :, 3] * dt) & (cr >= rxd[None, :, 3] * dr)
    row = (torch.arange(n, device=pts.device, dtype=torch.int64) * t1)[None, :]
    flat = sig.reshape(-1, 2)
    if nearest:
        i0 = torch.floor(idx).clamp(0, t - 1).to(torch.int64)
        v = flat[row + i0]
        re, im = v[..., 0], v[..., 1]
    else:
        fl = torch.floor(idx).clamp(0, t - 1)
        w = (idx - fl).clamp(0, 1)
        i0 = row + fl.to(torch.int64)
        v0 = flat[i0]
        v1 = flat[i0 + 1]
        re = v0[..., 0] + w * (v1[..., 0] - v0[..., 0])
        im = v0[..., 1] + w * (v1[..., 1] - v0[..., 1])
    zero = torch.zeros((), dtype=re.dtype, device=re.device)
    re = torch.where(valid, re, zero)
    im = torch.where(valid, im, zero)
    if with_phase:
        ph = d * phase_k
        c, s = torch.cos(ph), torch.sin(ph)
        re, im = re * c - im * s, re * s + im * c
    return re.sum(1), im.sum(1)


_COMPILED: dict[str, object] = {}


def _kernel(backend: str, device: torch.device):
    """The block kernel: compiled once per process (per device type), eager as fallback."""
    if backend == "eager":
        return _bp_block
    key = device.type
    if key not in _COMPILED:
        try:
            _COMPILED[key] = torch.compile(_bp_block, dynamic=False, fullgraph=True)
        except Exception as exc:  # torch.compile unavailable on this platform
            if backend == "compiled":
                raise ShsasError(f"backprojection: torch.compile failed ({exc})") from exc
            log.warning("torch.compile unavailable (%s); using the eager kernel", exc)
            _COMPILED[key] = _bp_block
    return _COMPILED[key]


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
    kernel = _kernel(cfg.backend, dev)
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

    nb = cfg.voxel_block
    pc = min(cfg.ping_chunk, n)
    out = np.zeros(v_total, np.complex128)
    chunks = [(a, min(a + pc, n)) for a in range(0, n, pc)]
    total_steps = len(chunks) * math.ceil(v_total / nb)
    step = 0
    pts_all = torch.as_tensor(points - origin, **f32)
    for a, b in chunks:
        check_stop(should_stop)
        m = b - a
        s = sig[a:b].to(dev)
        s = upsample_signals(s.to(torch.complex64), up)
        tu = s.shape[1]
        # Pad pings to a fixed chunk size (zero signal) so the compiled kernel sees one shape.
        buf = torch.zeros((pc, tu + 1, 2), **f32)
        buf[:m, :tu] = torch.view_as_real(s.to(torch.complex64))
        pos = np.zeros((pc, 3, 2))
        pos[:m, :, 0], pos[:m, :, 1] = tx[a:b] - origin, rx[a:b] - origin
        tx_t = torch.as_tensor(pos[..., 0], **f32)
        rx_t = torch.as_tensor(pos[..., 1], **f32)
        a_np = np.zeros(pc)
        a_np[:m] = t0[a:b] * fs_u
        a_t = torch.as_tensor(a_np, **f32)
        txd = np.zeros((pc, 4))
        rxd = np.zeros((pc, 4))
        txd[:, 3] = rxd[:, 3] = -2.0
        txd[:m], rxd[:m] = txd_all[a:b], rxd_all[a:b]
        txd_t, rxd_t = torch.as_tensor(txd, **f32), torch.as_tensor(rxd, **f32)
        for v0 in range(0, v_total, nb):
            v1 = min(v0 + nb, v_total)
            p = pts_all[v0:v1]
            if v1 - v0 < nb and v_total > nb:  # pad the last block to the common shape
                p = torch.cat([p, p.new_zeros((nb - (v1 - v0), 3))])
            re, im = kernel(p, tx_t, rx_t, a_t, buf, k, phase_k, txd_t, rxd_t,
                            nearest, with_phase, with_beams)
            vals = torch.complex(re, im)[: v1 - v0].cpu().numpy()
            out[v0:v1] += vals
            step += 1
            progress(step / total_steps, "backprojection", {})
    return out.astype(np.complex64)


def default_signals(survey: Survey) -> tuple[np.ndarray, str]:
    """Signals to image when none are given: ``extras["deconvolved"]``, else the matched filter.

    Returns ((N, T) complex64, name of the choice).
    """
    ex = survey.extras.get("deconvolved")
    if ex is not None and ex.shape == survey.shape:
        return ex.astype(np.complex64), "deconvolved"
    from .signal import matched_filter

    return matched_filter(survey), "matched"


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
    from .signal import baseband, crop_to_scene

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


def save_volume(volume: Volume, out_dir: str | os.PathLike, extra: dict | None = None) -> dict[str, Path]:
    """Write ``volume.npy`` (complex64 values), ``magnitude.npy`` (float32) and ``grid.json``.

    Files are written to a temporary name and renamed, so readers never see partial files.
    Returns the paths by name.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"volume": out / "volume.npy", "magnitude": out / "magnitude.npy", "grid": out / "grid.json"}

    def put(path: Path, arr: np.ndarray) -> None:
        tmp = path.with_name(path.name + ".tmp.npy")
        np.save(tmp, arr)
        os.replace(tmp, path)

    put(paths["volume"], np.asarray(volume.values))
    put(paths["magnitude"], volume.magnitude())
    g = volume.grid
    info = {"name": volume.name, "box_min": list(g.box_min), "box_max": list(g.box_max),
            "shape": list(g.shape), "spacing": g.spacing.tolist(),
            "order": "C (x slowest, z fastest); voxel (i,j,k) centre = box_min + (idx + 0.5) * spacing",
            "dtype": str(np.asarray(volume.values).dtype), **(extra or {})}
    tmp = paths["grid"].with_name("grid.json.tmp")
    tmp.write_text(json.dumps(info, indent=2))
    os.replace(tmp, paths["grid"])
    return paths
