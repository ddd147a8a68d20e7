"""Time-resolved volume rendering of pings from a scattering field (paper §4.4; docs/neural.md).

For ping ``n`` with TX ``o_T`` and RX ``o_R`` and a range bin of two-way path ``r_k``:

    s_hat(r_k) = A * sum_rays w_km T_km^2 sigma(x_km, omega_km) g_km

* ``x_km``: where TX ray ``m`` meets the ellipsoid of bin ``k`` (:mod:`.geometry`);
* ``omega_km``: unit direction from the receiver to ``x_km`` (the SH look direction);
* ``T_km^2``: two-way transmittance (:mod:`.transmittance`), ``T(x, o_R) ≈ T(o_T, x)``;
* ``g_km = max(0, n_km . (o_T - x)/|o_T - x|)``: Lambertian term; ``n_km`` is the field's normal
  at ``x_km``, or with ``normal_window = W > 1`` the normalised negative sum of the field's
  gradients at samples ``k-W+1 .. k`` of the same ray (:func:`windowed_normals`);
* ``w_km``: quadrature weight. ``weighting="solid_angle"`` (default): ``(Omega / M) R_T / (R_R
  cos psi)`` — the rays are uniform in TX solid angle, each standing for ``Omega / M``
  steradians; the factor turns that into ellipsoid area with the point-scatterer spreading
  ``1 / (R_T R_R)`` (:func:`.geometry.area_jacobian`), so ``s_hat`` approximates
  ``∫_E sigma g T^2 / (R_T R_R) dA``. ``weighting="sum"``: ``w = 1`` (plain sum over rays, as in
  the public code of Reed et al. and SH-SAS).
* beam patterns ``b_T = b_R = 1`` inside the TX cone (rays are only cast there), as in the paper.
* ``A``: a global real amplitude (the trainer fits it, see :mod:`shsas_core.neural.train`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from shsas_core.common.errors import ShsasError
from shsas_core.common.heap import heap_cache
from shsas_core.data.geometry import two_way_range_bounds
from shsas_core.data.survey import sample_times
from shsas_core.neural.fields.base import device_dtype
from shsas_core.neural.fields.field import safe_normalize
from shsas_core.neural.render.geometry import (
    area_jacobian,
    intersect_focal,
    intersect_quadric,
    points_on_rays,
)
from shsas_core.neural.render.sampling import (
    beam_axes,
    bin_radii,
    cone_directions,
    cone_half_angles,
)
from shsas_core.neural.render.transmittance import transmittance, transmittance_cumprod
from shsas_core.spec.options import (
    NORMAL_WINDOW,
    NORMAL_WINDOW_HELP,
    NUM_BINS,
    NUM_RAYS,
    UNIFORM_FRACTION,
    NormalWindow,
    NumBins,
    NumRays,
    UniformFraction,
)


class RenderConfig(BaseModel):
    """How pings are rendered. Defaults run on a 2-core CPU."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # bounds and defaults shared with TrainConfig and the job spec (shsas_core.spec.options)
    num_bins: NumBins = NUM_BINS
    num_rays: NumRays = NUM_RAYS
    uniform_fraction: UniformFraction = UNIFORM_FRACTION
    beamwidth_deg: float | None = Field(None, gt=0, le=360,
                                        description="full TX cone angle; None: meta.tx_beamwidth_deg, "
                                        "else a cone covering the scene box")
    lambertian: bool = Field(True, description="multiply by max(0, n . to_tx) (needs normals)")
    normal_window: NormalWindow = Field(NORMAL_WINDOW, description=NORMAL_WINDOW_HELP)
    two_way_transmittance: bool = Field(True, description="T^2 (return leg ≈ transmit leg) instead of T")
    weighting: Literal["solid_angle", "sum"] = "solid_angle"
    backend: Literal["fast", "reference"] = Field(
        "fast", description="fast: focal closed-form intersection + cumsum transmittance; reference: "
        "ellipsoid-frame quadric + cumprod (the paper's form, same result)")


@dataclasses.dataclass
class PingGeometry:
    """Per-ping tensors the renderer needs, on the compute device.

    Attributes:
        tx, rx: (B, 3) m. axis: (B, 3) unit beam axes. half_angle: (B,) cone half-angles, rad.
    """

    tx: Tensor
    rx: Tensor
    axis: Tensor
    half_angle: Tensor


def ping_geometry(survey, index: np.ndarray | Sequence[int], device: torch.device | str = "cpu",
                  dtype: torch.dtype = torch.float32, beamwidth_deg: float | None = None) -> PingGeometry:
    """Gather TX/RX, beam axes and cone half-angles of the selected pings of a survey."""
    idx = np.asarray(index, dtype=np.int64)
    box = survey.meta.scene_box
    tx, rx = survey.tx[idx], survey.rx[idx]
    axis = beam_axes(tx, None if survey.tx_dir is None else survey.tx_dir[idx], box.center)
    bw = beamwidth_deg if beamwidth_deg is not None else survey.meta.tx_beamwidth_deg
    half = cone_half_angles(tx, axis, box.min, box.max, bw)

    def t(a: np.ndarray) -> Tensor:
        return torch.as_tensor(a, dtype=dtype, device=device)

    return PingGeometry(t(tx), t(rx), t(axis), t(half))


def sample_ellipsoids(geom: PingGeometry, radii: Tensor, dirs: Tensor, fast: bool = True) -> dict[str, Tensor]:
    """Sample points: each TX ray against each bin's ellipsoid.

    Args:
        geom: B pings. radii: (B, K) two-way paths, m, sorted ascending. dirs: (B, M, 3) unit rays.
    Returns:
        dict with ``x`` (B,K,M,3) m, ``l`` (B,K,M) m along the ray, ``valid`` (B,K,M) bool.
    """
    fn = intersect_focal if fast else intersect_quadric
    dist, valid = fn(geom.tx, geom.rx, dirs, radii)
    return {"x": points_on_rays(geom.tx, dirs, dist), "l": dist, "valid": valid}


def render_samples(field: torch.nn.Module, geom: PingGeometry, radii: Tensor, dirs: Tensor,
                   solid_angle: Tensor, cfg: RenderConfig, amplitude: Tensor | float = 1.0,
                   create_graph: bool | None = None) -> dict[str, Tensor]:
    """Render B pings at K bins each with the given rays (the differentiable core).

    Args:
        field: module with ``forward(x (P,3), dirs (P,3), with_normals, create_graph) -> dict``
            holding ``density`` (P,) and ``scattering`` (P,) complex (and ``normals`` (P,3)).
        geom: B pings. radii: (B, K) m, ascending per ping. dirs: (B, M, 3) unit TX rays.
        solid_angle: (B,) sr of the cones the rays cover. cfg: render options.
        amplitude: global real scale A (tensor to learn it).
        create_graph: passed to the field for its normals (default: grad mode).

    Returns:
        dict with ``signal`` (B, K) complex predicted samples, and per sample (B, K, M):
        ``x`` (…,3), ``valid``, ``density``, ``scattering``, ``transmittance``, ``lambertian``,
        ``weight``, and with ``cfg.normal_window > 1`` the field's ``gradient`` (B, K, M, 3).
    """
    b, k = radii.shape
    m = dirs.shape[1]
    fast = cfg.backend == "fast"
    s = sample_ellipsoids(geom, radii, dirs, fast=fast)
    x, valid = s["x"], s["valid"]
    look = x - geom.rx[:, None, None, :]
    look = look / look.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    out = field(x.reshape(-1, 3), look.reshape(-1, 3), with_normals=cfg.lambertian, create_graph=create_graph)
    vf = valid.to(x.dtype)
    density = out["density"].reshape(b, k, m) * vf
    sigma = out["scattering"].reshape(b, k, m)
    trans = (transmittance if fast else transmittance_cumprod)(density, s["l"], cfg.two_way_transmittance)
    gradient = None
    if not cfg.lambertian:
        g = torch.ones_like(density)
    elif cfg.normal_window > 1:
        gradient = out["gradient"].reshape(b, k, m, 3) * vf[..., None]
        g = lambertian_term(windowed_normals(gradient, cfg.normal_window), dirs)
    else:
        g = lambertian_term(out["normals"].reshape(b, k, m, 3), dirs)
    if cfg.weighting == "solid_angle":
        w = (solid_angle / m)[:, None, None] * area_jacobian(geom.tx, geom.rx, x, dirs)
    else:
        w = torch.ones_like(density)
    w = w * vf
    contrib = sigma * (w * trans * g).to(sigma.dtype)
    signal = contrib.sum(dim=-1) * amplitude
    res = {"signal": signal, "x": x, "valid": valid, "density": density, "scattering": sigma,
           "transmittance": trans, "lambertian": g, "weight": w}
    if gradient is not None:
        res["gradient"] = gradient
    return res


def windowed_normals(gradient: Tensor, window: int) -> Tensor:
    """Normals from field gradients summed along each ray over ``window`` samples.

    ``n_k = -normalize(Σ_{j=k-W+1..k} ∇_j)`` (``j >= 0``). Along a ray the sum's component on the
    ray is the density's rise over the window (a finite difference on a longer baseline). On a thin
    shell the sample's own gradient vanishes at the ridge and points back at the sonar past it, so
    with ``window = 1`` (the field's normals, ``-normalize(∇_k)``) only the near flank faces the
    sonar; with a window the part facing it reaches half a window past the ridge, centred on it.

    Args:
        gradient: (B, K, M, 3) ∇|σ_DC| at the samples, 1/m², bins ascending along each ray (0 at
            invalid samples). window: W >= 1 samples.

    Returns:
        (B, K, M, 3) unit normals (0 where the sum is 0).
    """
    if window < 1:
        raise ShsasError(f"windowed_normals: window must be >= 1, got {window}")
    total = torch.cumsum(gradient, dim=1)
    if window < gradient.shape[1]:
        before = torch.cat([torch.zeros_like(total[:, :window]), total[:, :-window]], dim=1)
        total = total - before
    return -safe_normalize(total)


def lambertian_term(normals: Tensor, dirs: Tensor) -> Tensor:
    """``g = max(0, n . (o_T - x)/|o_T - x|)``: normals (B, K, M, 3) unit, dirs (B, M, 3) unit TX
    rays -> (B, K, M)."""
    return (-(normals * dirs[:, None, :, :]).sum(-1)).clamp_min(0.0)  # (o_T - x)/|o_T - x| = -u


def render_pings(field: torch.nn.Module, geom: PingGeometry, radii: Tensor, cfg: RenderConfig,
                 generator: torch.Generator | None, amplitude: Tensor | float = 1.0,
                 jitter: bool = True, create_graph: bool | None = None) -> dict[str, Tensor]:
    """Render B pings at the given bins with ``cfg.num_rays`` fresh stratified rays per ping.

    Args:
        radii: (B, K) two-way paths of the bins, m, ascending. generator: CPU generator for the
        ray jitter (None or ``jitter=False``: stratum centres, deterministic).
    Returns:
        as :func:`render_samples`; ``signal`` is (B, K) complex.
    """
    dirs, omega = cone_directions(geom.axis, geom.half_angle, cfg.num_rays, generator, jitter=jitter)
    return render_samples(field, geom, radii, dirs, omega, cfg, amplitude, create_graph)


@torch.no_grad()
def render_transients(field: torch.nn.Module, survey, ping_indices: Sequence[int] | np.ndarray,
                      cfg: RenderConfig | None = None, amplitude: float = 1.0,
                      device: torch.device | str | None = None, seed: int = 0,
                      bins_per_chunk: int = 64) -> np.ndarray:
    """Novel-view transient synthesis: the complex signal of whole pings on their time axis.

    Every sample ``k`` of ping ``n`` (two-way path ``c (t0_n + k / fs)``) inside the scene's
    range window is rendered with ``cfg.num_rays`` rays (seeded jitter, the same rays for all
    bins of a ping, so transmittance runs over all of them in order); samples outside the
    window are 0. The pings may be any poses (held-out pings, or a survey made up of new poses).

    Args:
        field: trained field. survey: geometry, time axis and scene box (samples not needed).
        ping_indices: which pings. cfg: render options (num_bins is ignored). amplitude: the
        trainer's fitted amplitude (``FitResult.amplitude``). device: default the field's.
        seed: ray jitter seed. bins_per_chunk: bins evaluated per field call (memory bound).

    Returns:
        (len(ping_indices), T) complex64, analytic passband (baseband for baseband surveys, see
        :func:`passband_factor`).
    """
    cfg = cfg or RenderConfig()
    own_device, dtype = device_dtype(field)
    device = own_device if device is None else device
    idx = np.asarray(ping_indices, dtype=np.int64)
    n_t = survey.num_samples
    if idx.size and (idx.min() < 0 or idx.max() >= survey.num_pings):
        raise ShsasError(f"render_transients: ping index out of range 0..{survey.num_pings - 1}")
    radii_all = bin_radii(survey.t0[idx], survey.meta.fs, survey.meta.sound_speed, n_t)
    r_lo, r_hi = two_way_range_bounds(survey.tx[idx], survey.rx[idx], survey.meta.scene_box)
    out = np.zeros((len(idx), n_t), dtype=np.complex64)
    gen = torch.Generator().manual_seed(int(seed))
    # CPU: keep freed buffers in the heap between pings (measured on 24 pings x 4096 rays: 12.6–16.1 s
    # -> 10.1 s wall, 5–9 s -> 0.3 s of system time spent zeroing remapped pages)
    with heap_cache(torch.device(device).type == "cpu"):
        _render_rows(field, survey, idx, radii_all, r_lo, r_hi, cfg, device, dtype, gen, bins_per_chunk, out)
    out *= np.complex64(amplitude)
    factor = passband_factor(survey, idx)
    if factor is not None:  # back to the survey's baseband convention
        out = (out * np.conj(factor)).astype(np.complex64)
    return out


def _render_rows(field: torch.nn.Module, survey, idx: np.ndarray, radii_all: np.ndarray, r_lo: np.ndarray,
                 r_hi: np.ndarray, cfg: RenderConfig, device, dtype: torch.dtype, gen: torch.Generator,
                 bins_per_chunk: int, out: np.ndarray) -> None:
    """The per-ping loop of :func:`render_transients`: fills ``out`` (len(idx), T) in place, A = 1."""
    # a window of normals reaches back across chunks: it is applied to the whole ray below
    windowed = cfg.lambertian and cfg.normal_window > 1
    keys = ("density", "scattering", "lambertian", "weight") + (("gradient",) if windowed else ())
    for row, n in enumerate(idx):
        geom = ping_geometry(survey, [n], device, dtype, cfg.beamwidth_deg)
        keep = np.nonzero((radii_all[row] >= r_lo[row]) & (radii_all[row] <= r_hi[row]))[0]
        if keep.size == 0:
            continue
        dirs, omega = cone_directions(geom.axis, geom.half_angle, cfg.num_rays, gen, jitter=True)
        radii = torch.as_tensor(radii_all[row, keep], dtype=dtype, device=device)[None, :]
        # evaluate the field chunk by chunk, then transmittance over the whole ray at once
        parts: dict[str, list[Tensor]] = {key: [] for key in (*keys, "l")}
        for c0 in range(0, radii.shape[1], bins_per_chunk):
            rc = radii[:, c0:c0 + bins_per_chunk]
            with torch.enable_grad():  # normals need autograd even when nothing is trained
                r = render_samples(field, geom, rc, dirs, omega, cfg, 1.0, create_graph=False)
            s = sample_ellipsoids(geom, rc, dirs, fast=cfg.backend == "fast")
            for key in keys:
                parts[key].append(r[key].detach())
            parts["l"].append(s["l"])
        cat = {k: torch.cat(v, dim=1) for k, v in parts.items()}
        if windowed:
            cat["lambertian"] = lambertian_term(windowed_normals(cat["gradient"], cfg.normal_window), dirs)
        trans = transmittance(cat["density"], cat["l"], cfg.two_way_transmittance)
        sig = (cat["scattering"] * (cat["weight"] * trans * cat["lambertian"]).to(cat["scattering"].dtype)).sum(-1)
        out[row, keep] = sig[0].cpu().numpy().astype(np.complex64)


def passband_factor(survey, ping_indices: Sequence[int] | np.ndarray | None = None) -> np.ndarray | None:
    """``exp(j 2π f_c t)`` on the sample times of baseband surveys, None for passband ones.

    The renderer predicts analytic passband samples: a scatterer exactly on a bin's ellipsoid adds
    to that bin with the phase of its own scattering coefficient. Baseband signals
    ``s_bb(t) = s(t) exp(-j 2π f_c t)`` are therefore multiplied by this factor before training
    and rendered transients by its conjugate, so every survey kind uses the same field.

    Returns:
        (len, T) complex128 or None.
    """
    if survey.meta.signal_kind != "baseband":
        return None
    idx = np.arange(survey.num_pings) if ping_indices is None else np.asarray(ping_indices, dtype=np.int64)
    t = sample_times(survey.t0[idx], survey.meta.fs, survey.num_samples)
    return np.exp(2j * np.pi * float(survey.meta.carrier_hz) * t)


def signal_errors(pred: np.ndarray | Tensor, meas: np.ndarray | Tensor) -> dict[str, float]:
    """Novel-view signal errors in the layout of the paper's supplement Table 4.

    Args:
        pred, meas: complex arrays of the same shape (e.g. (N, T)).
    Returns:
        ``l1_real``, ``l1_imag``, ``l1_abs`` (mean absolute error of the real part, imaginary part
        and magnitude) and ``mse_real``, ``mse_imag``, ``mse_abs`` (mean squared errors), in the
        units of the signals.
    """
    p = pred.detach().cpu().numpy() if isinstance(pred, Tensor) else np.asarray(pred)
    q = meas.detach().cpu().numpy() if isinstance(meas, Tensor) else np.asarray(meas)
    if p.shape != q.shape:
        raise ShsasError(f"signal_errors: shapes differ, {p.shape} vs {q.shape}")
    if p.size == 0:
        raise ShsasError("signal_errors: empty signals")
    p, q = p.astype(np.complex128), q.astype(np.complex128)
    out = {}
    for name, a, b in (("real", p.real, q.real), ("imag", p.imag, q.imag), ("abs", np.abs(p), np.abs(q))):
        out[f"l1_{name}"] = float(np.mean(np.abs(a - b)))
        out[f"mse_{name}"] = float(np.mean((a - b) ** 2))
    return out
