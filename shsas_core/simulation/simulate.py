"""Simulate a bistatic SAS survey of a mesh (or of given point scatterers) with known truth.

Model (details, the sampling rule and the SNR definition in docs/simulation.md). For ping n
with transmitter ``o_T``, receiver ``o_R`` and scatterer i at ``x_i`` with normal ``n_i``::

    s_n(t) = Σ_i v_in · a_in · p(t - (|x_i - o_T| + |x_i - o_R|) / c)   (+ noise)

``p`` is the transmitted LFM pulse (band-limited, so a fractional delay is exact), ``v_in`` is 1
when the point faces and sees both the TX and the RX (shadow rays against the mesh) and lies in
both beam cones (when beam widths are set), 0 otherwise, and the amplitude is

    a_in = w_i · (L_in + k_s · max(0, n_i·h)^m) · S_in

with ``w_i`` the point weight (area it stands for, times optional random amplitude), ``L`` the
Lambertian term (``cos θ_T`` toward the TX by default, like the SH-SAS renderer; or toward the
RX, the geometric mean of both, or none), the optional directional lobe around the bistatic
half vector ``h = unit(ω_T + ω_R)`` (Blinn-Phong), and ``S`` the optional two-way spherical
spreading ``1 / (|x - o_T| · |x - o_R|)`` in m⁻² (so 1 at 1 m each way). An optional random
phase per point (a diffuse, speckled surface) rotates the analytic pulse of that point.

Synthesis never rounds a delay to a whole sample: each contribution is splatted with linear
weights onto a grid ``upsample`` times finer than the output, the fine grid is Fourier
transformed, its in-band part is multiplied by the pulse spectrum and divided by the spectrum
of the linear kernel (sinc²), and the result is transformed back at the output rate. The error
is from the kernel's spectral images only, about ``(f / (U·fs))²`` in amplitude: below 2e-3
(-55 dB) at 30 kHz for U = 8 and fs = 100 kHz (see tests/core/simulation/test_simulate.py).

Pings are processed in chunks of at most ``chunk_pairs`` point-ping pairs, so memory stays
bounded whatever the survey size; the shadow rays of a whole chunk go to the ray caster at once.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from typing import Literal

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy import fft as sfft

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import ProgressFn, StopFn, check_stop
from shsas_core.data.geometry import two_way_range_bounds
from shsas_core.data.pulse import lfm_pulse
from shsas_core.data.survey import PulseParams, SceneBox, Survey, SurveyMeta
from shsas_core.simulation.scatterers import (
    Occluder,
    Scatterers,
    points_for_spacing,
    sample_surface,
)
from shsas_core.simulation.shapes import check_mesh, load_mesh
from shsas_core.simulation.trajectory import TrajectoryConfig, make_trajectory

__all__ = [
    "PulseParams",
    "ScatteringConfig",
    "SimulationConfig",
    "TrajectoryConfig",
    "inband_power",
    "measured_snr_db",
    "pointing",
    "record_window",
    "simulate",
    "simulate_shape",
]


class _Cfg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ScatteringConfig(_Cfg):
    """How the surface scatters (see the module docstring for the formula)."""

    spacing_fraction: float = Field(
        0.25, gt=0, le=1,
        description="mean point spacing sqrt(area/M) as a fraction of the shortest wavelength")
    max_points: int = Field(2_000_000, ge=1, description="refuse meshes needing more surface points")
    lambert: Literal["tx", "rx", "both", "none"] = Field(
        "tx", description="Lambertian cosine toward the TX (renderer's g), the RX, their geometric mean, or none")
    specular_weight: float = Field(0.0, ge=0, description="k_s: peak of the directional lobe relative to the Lambertian peak")
    specular_exponent: float = Field(20.0, gt=0, description="m: sharpness of the directional lobe")
    spreading: bool = Field(False, description="two-way spherical spreading 1/(R_T R_R)")
    random_phase: bool = Field(False, description="uniform random phase per point (diffuse, speckled surface)")
    random_amplitude: bool = Field(False, description="Rayleigh random amplitude per point, unit mean power")
    two_sided: bool = Field(False, description="surfaces scatter from both sides (open meshes)")
    occlusion: bool = Field(True, description="shadow rays against the mesh (off: every facing point counts)")
    tx_beamwidth_deg: float | None = Field(
        None, gt=0, le=360, description="full TX cone angle, degrees; None: omnidirectional")
    rx_beamwidth_deg: float | None = Field(
        None, gt=0, le=360, description="full RX cone angle, degrees; None: omnidirectional")
    ray_backend: Literal["auto", "embree", "triangle"] = "auto"
    ray_offset: float = Field(1e-5, ge=0, description="lift of shadow-ray origins along the normal, m")


class SimulationConfig(_Cfg):
    """Everything that defines a simulated survey. Defaults follow the paper's simulations:
    10-30 kHz LFM, 1 ms, Tukey 0.1, 100 kHz sampling, c = 343 m/s, 20 dB SNR."""

    trajectory: TrajectoryConfig = TrajectoryConfig()
    pulse: PulseParams = PulseParams()
    fs: float = Field(100e3, gt=0, description="sample rate, Hz")
    sound_speed: float = Field(343.0, ge=300, le=1600, description="m/s")
    scattering: ScatteringConfig = ScatteringConfig()
    snr_db: float | None = Field(20.0, ge=-60, le=200, description="in-band SNR, dB; None: no noise")
    seed: int = Field(0, ge=0, description="seed of surface sampling, random point terms and noise")
    keep_clean: bool = Field(False, description="store the noise-free signal as extras['clean']")
    scene_box: SceneBox | None = Field(None, description="scene box; default: mesh/points bounds plus scene_margin")
    scene_margin: float = Field(0.02, ge=0, description="margin around the bounds for the default scene box, m")
    upsample: int = Field(8, ge=2, le=64, description="fine-grid factor of the delay splatting")
    chunk_pairs: int = Field(1_000_000, ge=1000, description="point-ping pairs held at once")
    guard_samples: int = Field(8, ge=0, le=10_000, description="extra samples before and after the range window")
    threads: int | None = Field(None, ge=1, le=256, description="ray-casting threads; None: one per CPU")

    @model_validator(mode="after")
    def _nyquist(self) -> SimulationConfig:
        if self.fs <= 2 * self.pulse.f_max:
            raise ValueError(f"fs={self.fs:g} Hz is not above twice the top chirp frequency "
                             f"({2 * self.pulse.f_max:g} Hz)")
        return self

    @property
    def wavelength_min(self) -> float:
        """Shortest wavelength of the pulse band, m."""
        return self.sound_speed / self.pulse.f_max


# -- geometry helpers -------------------------------------------------------------------------

def record_window(tx: np.ndarray, rx: np.ndarray, box: SceneBox, c: float, fs: float,
                  pulse_len: int, guard: int) -> tuple[np.ndarray, int]:
    """Per-ping start time and a common length that cover every echo from the scene box.

    The window of ping n starts ``guard`` samples before the earliest two-way path to the box
    (whole samples after transmit) and runs past the latest path plus the pulse length.

    Returns:
        ``(t0, T)``: (N,) float64 start times, s (multiples of 1/fs), and the samples per ping.
    """
    r_min, r_max = two_way_range_bounds(tx, rx, box)
    first = np.maximum(np.floor(r_min / c * fs) - guard, 0).astype(np.int64)
    last = np.ceil(r_max / c * fs).astype(np.int64) + pulse_len + guard
    return first / fs, int(np.max(last - first))


def default_scene_box(bounds: np.ndarray, margin: float) -> SceneBox:
    """Bounds (2, 3) grown by ``margin`` on every side."""
    lo = np.asarray(bounds[0], dtype=np.float64) - margin
    hi = np.asarray(bounds[1], dtype=np.float64) + margin
    hi = np.maximum(hi, lo + 1e-3)  # a single point still gets a box
    return SceneBox(min=tuple(float(v) for v in lo), max=tuple(float(v) for v in hi))


# -- synthesis --------------------------------------------------------------------------------

class _Synth:
    """Fine-grid splatting plus FFT filtering for a fixed output window (see module doc)."""

    def __init__(self, pulse: np.ndarray, num_samples: int, upsample: int):
        p = len(pulse)
        self.T = num_samples
        self.U = upsample
        self.pad = p + 2  # room for echoes that start up to a pulse length before the window
        # an odd length has no Nyquist bin, whose phase a real signal could not carry (the
        # sampled Tukey LFM still has ~2% of its peak spectrum there)
        n = num_samples + self.pad
        while n % 2 == 0 or sfft.next_fast_len(n, real=True) != n:
            n += 1
        self.n = n
        self.nf = self.n * upsample
        k = np.arange(self.n // 2 + 1)
        # undo the linear kernel's sinc² roll-off
        self.h = sfft.rfft(pulse, n=self.n) / np.sinc(k / self.nf) ** 2

    def render(self, ping: np.ndarray, delay: np.ndarray, amp: np.ndarray,
               quad: np.ndarray | None, num_pings: int) -> np.ndarray:
        """Sum echoes into a (num_pings, T) float64 block.

        Args:
            ping: (K,) local ping index of each contribution.
            delay: (K,) delay after the ping's t0, in output samples (fractional).
            amp: (K,) in-phase amplitude; quad: (K,) quadrature amplitude or None.
        """
        u = (delay + self.pad) * self.U
        keep = (u >= 0) & (u < self.nf - 1)
        if not np.all(keep):
            ping, u, amp = ping[keep], u[keep], amp[keep]
            quad = None if quad is None else quad[keep]
        i0 = np.floor(u).astype(np.int64)
        frac = u - i0
        base = ping * self.nf + i0
        size = num_pings * self.nf
        idx = np.concatenate([base, base + 1])

        def splat(a: np.ndarray) -> np.ndarray:
            w = np.concatenate([a * (1 - frac), a * frac])
            return np.bincount(idx, weights=w, minlength=size).reshape(num_pings, self.nf)

        nb = self.n // 2 + 1
        spec = sfft.rfft(splat(amp), axis=1)[:, :nb]
        if quad is not None:
            # Re{e^{jφ} p_analytic}: the quadrature part is the Hilbert pair, +j on f > 0
            spec = spec + 1j * sfft.rfft(splat(quad), axis=1)[:, :nb]
        out = sfft.irfft(spec * self.h, n=self.n, axis=1)
        return out[:, self.pad:self.pad + self.T]


class _Scene:
    """Per-simulation constants of the scatterers, computed once for all chunks."""

    def __init__(self, sc: Scatterers, weight: np.ndarray, phase: np.ndarray | None,
                 cfg: ScatteringConfig, occ: Occluder | None):
        self.sc, self.weight, self.phase, self.cfg, self.occ = sc, weight, phase, cfg, occ
        x = sc.points
        self.xx = np.einsum("ij,ij->i", x, x)
        self.xt = np.ascontiguousarray(x.T)
        self.nx = self.nt = None
        if sc.normals is not None:
            self.nx = np.einsum("ij,ij->i", sc.normals, x)
            self.nt = np.ascontiguousarray(sc.normals.T)
        self.start = self.start_back = None
        if occ is not None:
            # shadow rays leave from just above the surface so they do not hit their own face
            if sc.normals is None:
                self.start = occ.to_frame(x)
            else:
                self.start = occ.to_frame(x + cfg.ray_offset * sc.normals)
                if cfg.two_sided:
                    self.start_back = occ.to_frame(x - cfg.ray_offset * sc.normals)


def _pair_dot(p: np.ndarray, vt: np.ndarray) -> np.ndarray:
    """(B, M) dot products of sensors p (B, 3) with vectors vt (3, M), as three outer
    products: a k = 3 matrix product is slow in BLAS and fights over threads."""
    out = np.multiply.outer(p[:, 0], vt[0])
    out += np.multiply.outer(p[:, 1], vt[1])
    out += np.multiply.outer(p[:, 2], vt[2])
    return out


def _in_cone(p: np.ndarray, d: np.ndarray, scene: _Scene, k: np.ndarray, pi: np.ndarray,
             r: np.ndarray, width_deg: float) -> np.ndarray:
    """Whether pair k's point lies inside the cone of full angle ``width_deg`` around the unit
    pointing vector d (B, 3) of sensors p (B, 3); r (K,) the pair ranges."""
    along = _pair_dot(d, scene.xt).ravel()[k] - np.einsum("ij,ij->i", p, d)[pi]  # (x - o)·d
    return along >= np.cos(np.radians(width_deg / 2)) * r


def _chunk(scene: _Scene, tx: np.ndarray, rx: np.ndarray, t0: np.ndarray,
           cfg: SimulationConfig, synth: _Synth, tx_dir: np.ndarray | None = None,
           rx_dir: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Echoes of all scatterers for one chunk of B pings: (B, T) float64 and #contributions."""
    s, sc, occ = cfg.scattering, scene.sc, scene.occ
    b, m = len(tx), len(sc)
    x, nrm = sc.points, sc.normals
    flip = None
    if nrm is not None:
        # n·(o - x) for every pair, (B, M); its sign says whether the point faces the sensor
        ft = _pair_dot(tx, scene.nt)
        ft -= scene.nx
        fr = _pair_dot(rx, scene.nt)
        fr -= scene.nx
        if s.two_sided:  # face the side the TX is on
            flip = ft < 0
            np.negative(ft, out=ft, where=flip)
            np.negative(fr, out=fr, where=flip)
        k = np.flatnonzero((ft > 0) & (fr > 0))           # facing both sensors
    else:
        k = np.arange(b * m)
    pi = k // m
    mi = k - pi * m
    # |o - x|² = |o|² + |x|² - 2 o·x; in float64 the cancellation costs ~1e-16 m at these ranges
    r_t = np.einsum("ij,ij->i", tx, tx)[pi] + scene.xx[mi] - 2.0 * _pair_dot(tx, scene.xt).ravel()[k]
    r_r = np.einsum("ij,ij->i", rx, rx)[pi] + scene.xx[mi] - 2.0 * _pair_dot(rx, scene.xt).ravel()[k]
    r_t = np.sqrt(np.maximum(r_t, 0.0, out=r_t), out=r_t)
    r_r = np.sqrt(np.maximum(r_r, 0.0, out=r_r), out=r_r)
    if s.tx_beamwidth_deg is not None or s.rx_beamwidth_deg is not None:
        keep = np.ones(len(k), dtype=bool)
        if s.tx_beamwidth_deg is not None:
            keep &= _in_cone(tx, tx_dir, scene, k, pi, r_t, s.tx_beamwidth_deg)
        if s.rx_beamwidth_deg is not None:
            keep &= _in_cone(rx, rx_dir, scene, k, pi, r_r, s.rx_beamwidth_deg)
        k, pi, mi, r_t, r_r = k[keep], pi[keep], mi[keep], r_t[keep], r_r[keep]
    if occ is not None and len(k):
        # TX leg first; only pairs that see the TX need the RX ray
        if flip is None:
            start = scene.start[mi]
        else:
            back = flip.ravel()[k]
            start = np.where(back[:, None], scene.start_back[mi], scene.start[mi])
        free = ~occ.blocked(start, occ.to_frame(tx)[pi])
        k, pi, mi, r_t, r_r, start = k[free], pi[free], mi[free], r_t[free], r_r[free], start[free]
        free = ~occ.blocked(start, occ.to_frame(rx)[pi])
        k, pi, mi, r_t, r_r = k[free], pi[free], mi[free], r_t[free], r_r[free]
    if nrm is None:
        a = np.ones(len(k))
    else:
        c_t, c_r = ft.ravel()[k] / r_t, fr.ravel()[k] / r_r  # cos θ_T, cos θ_R
        del ft, fr
        if s.lambert == "tx":
            a = c_t
        elif s.lambert == "rx":
            a = c_r
        elif s.lambert == "both":
            a = np.sqrt(c_t * c_r)
        else:
            a = np.ones(len(k))
        if s.specular_weight > 0:
            # Blinn-Phong lobe around the bistatic half vector h = unit(ω_T + ω_R)
            xm = x[mi]
            h = (tx[pi] - xm) / r_t[:, None] + (rx[pi] - xm) / r_r[:, None]
            n = nrm[mi] if flip is None else nrm[mi] * np.where(flip.ravel()[k], -1.0, 1.0)[:, None]
            cos_h = np.einsum("ij,ij->i", n, h) / np.maximum(np.linalg.norm(h, axis=1), 1e-12)
            a = a + s.specular_weight * np.maximum(cos_h, 0.0) ** s.specular_exponent
    if s.spreading:
        a = a / (r_t * r_r)
    a = a * scene.weight[mi]
    delay = ((r_t + r_r) / cfg.sound_speed - t0[pi]) * cfg.fs
    if scene.phase is None:
        block = synth.render(pi, delay, a, None, b)
    else:
        ph = scene.phase[mi]
        block = synth.render(pi, delay, a * np.cos(ph), a * np.sin(ph), b)
    return block, len(k)


# -- noise ------------------------------------------------------------------------------------

def _band_weights(num_samples: int, fs: float, f_lo: float, f_hi: float) -> np.ndarray:
    """Parseval weights of the rfft bins inside [f_lo, f_hi] (2 for interior bins, 1 for DC
    and Nyquist, 0 outside), so ``Σ w_k |X_k|² / T²`` is the in-band mean power per sample."""
    f = sfft.rfftfreq(num_samples, 1 / fs)
    w = np.where((f >= min(f_lo, f_hi)) & (f <= max(f_lo, f_hi)), 2.0, 0.0)
    w[0] /= 2
    if num_samples % 2 == 0:
        w[-1] /= 2
    return w


def inband_power(x: np.ndarray, fs: float, f_lo: float, f_hi: float) -> float:
    """Mean power per sample of the part of ``x`` (..., T) real inside [f_lo, f_hi], i.e. the
    power of ``x`` after an ideal band-pass over each row (Parseval on the rfft)."""
    t = x.shape[-1]
    w = _band_weights(t, fs, f_lo, f_hi)
    spec = sfft.rfft(np.asarray(x, dtype=np.float64), axis=-1)
    rows = int(np.prod(x.shape[:-1]))
    return float(np.sum((spec.real**2 + spec.imag**2) @ w) / (t * t * rows))


def measured_snr_db(signal: np.ndarray, noise: np.ndarray, fs: float, f_lo: float, f_hi: float) -> float:
    """In-band SNR, dB: :func:`inband_power` of ``signal`` over that of ``noise`` (both (N, T))."""
    return float(10 * np.log10(inband_power(signal, fs, f_lo, f_hi) / inband_power(noise, fs, f_lo, f_hi)))


# -- main entry points ------------------------------------------------------------------------

def _weights(sc: Scatterers, cfg: SimulationConfig, rng: np.random.Generator
             ) -> tuple[np.ndarray, np.ndarray | None]:
    m = len(sc)
    w = np.ones(m) if sc.amplitude is None else sc.amplitude.copy()
    if cfg.scattering.random_amplitude:
        w *= rng.rayleigh(scale=np.sqrt(0.5), size=m)  # E[A²] = 1
    phase = sc.phase
    if cfg.scattering.random_phase:
        extra = rng.uniform(0, 2 * np.pi, size=m)
        phase = extra if phase is None else phase + extra
    return w, phase


def simulate(
    mesh: trimesh.Trimesh | None,
    config: SimulationConfig | None = None,
    *,
    scatterers: Scatterers | None = None,
    progress: ProgressFn | None = None,
    should_stop: StopFn | None = None,
) -> Survey:
    """Simulate a survey of ``mesh`` (and/or explicit point scatterers).

    Args:
        mesh: ground-truth mesh in metres, z up; it is sampled into surface points (unless
            ``scatterers`` is given), occludes (shadow rays) and is stored as ground truth.
            None: only ``scatterers``, no occlusion, no ground truth.
        config: all settings (defaults: paper-like AirSAS survey, 10 heights x 360 angles).
        scatterers: explicit point scatterers instead of the sampled surface.
        progress: ``progress(fraction, "simulate", metrics)`` after each chunk of pings.
        should_stop: polled between chunks; raises ``Cancelled`` when it returns True.

    Returns:
        A real-valued Survey (samples (N, T) float32) with ``meta.platform = "simulated"``,
        the settings in ``meta.attrs``, ground truth when a mesh was given,
        ``extras["ping_index"]`` (N,) int64 (index in the full trajectory before any subset) and,
        with ``keep_clean``, ``extras["clean"]`` (N, T) float32.

    Raises:
        ShsasError: bad mesh, nothing to simulate, too many points, or noise asked for a
            survey in which no scatterer is visible.
    """
    cfg = config or SimulationConfig()
    if mesh is None and scatterers is None:
        raise ShsasError("give a mesh or point scatterers to simulate")
    if mesh is not None:
        check_mesh(mesh)
    root = np.random.SeedSequence(cfg.seed)
    seq_points, seq_terms, seq_noise = root.spawn(3)
    spacing = cfg.scattering.spacing_fraction * cfg.wavelength_min
    if scatterers is None:
        count = points_for_spacing(float(mesh.area), spacing)
        if count > cfg.scattering.max_points:
            raise ShsasError(
                f"the mesh ({mesh.area:.4g} m²) needs {count} surface points at spacing "
                f"{spacing * 1e3:.2f} mm, above max_points={cfg.scattering.max_points} "
                "(raise max_points or spacing_fraction, or scale the mesh to metres)")
        sc = sample_surface(mesh, count, seed=int(seq_points.generate_state(1)[0]))
    else:
        sc = scatterers
    weight, phase = _weights(sc, cfg, np.random.default_rng(seq_terms))

    tx, rx, index = make_trajectory(cfg.trajectory)
    bounds = np.stack([sc.points.min(0), sc.points.max(0)])
    if mesh is not None:  # the box holds the mesh and every scatterer
        bounds = np.stack([np.minimum(bounds[0], mesh.bounds[0]), np.maximum(bounds[1], mesh.bounds[1])])
    box = cfg.scene_box or default_scene_box(bounds, cfg.scene_margin)
    pulse = lfm_pulse(cfg.pulse.f_start, cfg.pulse.f_stop, cfg.pulse.duration, cfg.fs,
                      cfg.pulse.window, cfg.pulse.window_param)
    t0, num_t = record_window(tx, rx, box, cfg.sound_speed, cfg.fs, len(pulse), cfg.guard_samples)
    occ = Occluder(mesh, cfg.scattering.ray_backend, cfg.threads) if (
        mesh is not None and cfg.scattering.occlusion) else None

    tx_dir, rx_dir = pointing(cfg.trajectory, tx, rx, box)
    synth = _Synth(pulse, num_t, cfg.upsample)
    scene = _Scene(sc, weight, phase, cfg.scattering, occ)
    n = len(tx)
    clean = np.empty((n, num_t), dtype=np.float32)
    step = max(1, cfg.chunk_pairs // len(sc))
    contributions = 0
    power = 0.0
    start = time.perf_counter()
    try:
        for lo in range(0, n, step):
            check_stop(should_stop)
            hi = min(n, lo + step)
            block, k = _chunk(scene, tx[lo:hi], rx[lo:hi], t0[lo:hi], cfg, synth,
                              tx_dir[lo:hi], rx_dir[lo:hi])
            contributions += k
            power += inband_power(block, cfg.fs, cfg.pulse.f_start, cfg.pulse.f_stop) * block.size
            clean[lo:hi] = block
            if progress is not None:
                el = max(time.perf_counter() - start, 1e-9)
                progress(hi / n, "simulate", {"pings": float(hi), "pings_per_s": hi / el,
                                              "contributions_per_s": contributions / el})
    finally:
        if occ is not None:
            occ.close()
    signal_power = power / clean.size
    samples, sigma = _add_noise(clean, cfg, signal_power, np.random.default_rng(seq_noise))

    attrs: dict[str, str | float | int | bool] = {
        "simulator": "shsas_core.simulation.simulate",
        "config": json.dumps(_describe(cfg), sort_keys=True),
        "seed": cfg.seed,
        "num_scatterers": len(sc),
        "mean_spacing_m": float(np.sqrt(mesh.area / len(sc))) if (mesh is not None and scatterers is None) else -1.0,
        "visible_contributions": contributions,
        "signal_power_inband": signal_power,
        "noise_sigma": sigma,
        "snr_db": -1.0 if cfg.snr_db is None else float(cfg.snr_db),
        "snr_definition": "in-band: clean power / noise power, both within [f_start, f_stop]",
        "ray_backend": occ.backend if occ is not None else "none",
    }
    meta = SurveyMeta(fs=cfg.fs, sound_speed=cfg.sound_speed, pulse=cfg.pulse, signal_kind="real",
                      platform="simulated", scene_box=box, attrs=attrs,
                      tx_beamwidth_deg=cfg.scattering.tx_beamwidth_deg,
                      rx_beamwidth_deg=cfg.scattering.rx_beamwidth_deg)
    extras: dict[str, np.ndarray] = {"ping_index": index}
    if cfg.keep_clean:
        extras["clean"] = clean
    return Survey(
        tx=tx, rx=rx, samples=samples, t0=t0, meta=meta, pulse=pulse,
        tx_dir=tx_dir, rx_dir=rx_dir,
        gt_vertices=None if mesh is None else np.asarray(mesh.vertices, dtype=np.float64),
        gt_faces=None if mesh is None else np.asarray(mesh.faces, dtype=np.int64),
        extras=extras,
    )


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)


def pointing(traj: TrajectoryConfig, tx: np.ndarray, rx: np.ndarray, box: SceneBox
             ) -> tuple[np.ndarray, np.ndarray]:
    """Beam pointing vectors (N, 3) unit of TX and RX: at the scene-box centre, except on
    linear passes, which look broadside (perpendicular to the track, +y) and down to the
    centre's height."""
    c = box.center
    if traj.kind == "linear":
        def broadside(p: np.ndarray) -> np.ndarray:
            v = np.zeros_like(p)
            v[:, 1] = c[1] - p[:, 1]
            v[:, 2] = c[2] - p[:, 2]
            return _unit(v)

        return broadside(tx), broadside(rx)
    return _unit(c - tx), _unit(c - rx)


def _add_noise(clean: np.ndarray, cfg: SimulationConfig, signal_power: float,
               rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """White Gaussian noise whose in-band power is ``signal_power / 10^(snr/10)``.

    ``signal_power`` is the in-band power of the clean signal (:func:`inband_power`). White
    noise of variance σ² spreads its power evenly over the rfft bins, so its in-band share is
    σ²·Σw_k/T (about σ²·B/(fs/2)); σ is chosen so that share matches the SNR.
    """
    if cfg.snr_db is None:
        return (clean.copy() if cfg.keep_clean else clean), 0.0
    if not signal_power > 0:
        raise ShsasError("no scatterer is visible from any ping, so an SNR cannot be set "
                         "(check the trajectory and mesh units, or pass snr_db=None)")
    band = float(_band_weights(clean.shape[1], cfg.fs, cfg.pulse.f_start, cfg.pulse.f_stop).sum()
                 / clean.shape[1])
    sigma = float(np.sqrt(signal_power / 10 ** (cfg.snr_db / 10) / band))
    out = clean.copy() if cfg.keep_clean else clean
    rows = 4096  # fixed block size so the noise does not depend on the chunking
    for lo in range(0, len(out), rows):
        blk = rng.standard_normal((min(rows, len(out) - lo), out.shape[1]), dtype=np.float32)
        out[lo:lo + rows] += np.float32(sigma) * blk
    return out, sigma


def _describe(cfg: SimulationConfig) -> dict:
    d = cfg.model_dump(exclude={"trajectory"})
    d["trajectory"] = cfg.trajectory.describe()
    return d


def simulate_shape(
    name: str,
    heights: int = 10,
    angles: int = 360,
    snr_db: float | None = 20.0,
    seed: int = 0,
    *,
    progress: ProgressFn | None = None,
    should_stop: StopFn | None = None,
    **overrides: object,
) -> Survey:
    """Simulate a circular AirSAS-like survey of a built-in shape or a mesh file.

    Args:
        name: ``sphere``, ``cube``, ``torus``, ``scene`` or a mesh path (see shapes.load_mesh).
        heights, angles: circles and pings per circle.
        snr_db: in-band SNR in dB, or None for no noise.
        seed: seed of everything random.
        overrides: other SimulationConfig fields, e.g. ``keep_clean=True``,
            ``scattering=ScatteringConfig(specular_weight=2)``; a ``trajectory`` given here
            replaces the circular one (its heights/angles then win).
    """
    traj = overrides.pop("trajectory", None) or TrajectoryConfig(heights=heights, angles=angles)
    cfg = SimulationConfig(trajectory=traj, snr_db=snr_db, seed=seed, **overrides)
    return simulate(load_mesh(name), cfg, progress=progress, should_stop=should_stop)


def config_summary(cfg: SimulationConfig) -> Mapping[str, object]:
    """The settings recorded in ``meta.attrs['config']`` as a dict."""
    return _describe(cfg)
