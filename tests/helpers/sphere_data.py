"""Ideal pulse-deconvolved pings of a sphere, computed independently of the renderer.

The sphere surface is covered by area-weighted points; each point visible from both TX and RX
adds a band-limited analytic impulse ``a exp(j 2π f_c (t - τ)) sinc(B (t - τ))`` at its two-way
delay ``τ``, with ``a = dA max(0, n·to_tx) / (R_T R_R)`` (Lambertian, spherical spreading).
"""

from __future__ import annotations

import numpy as np

from shsas_core.data.survey import SceneBox, Survey, SurveyMeta, default_pulse


def fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def sphere_survey(n_pings: int = 48, center=(0.0, 0.0, 0.09), radius: float = 0.05,
                  ring: float = 0.6, samples: int = 256, n_points: int = 6000, coherent: bool = True):
    """Survey + ideal s_PD (N, T) complex64 for a sphere seen from a helix of pings.

    ``coherent=False`` replaces the analytic kernel by a real Gaussian envelope of standard
    deviation 1/(2B) (an incoherent, magnitude-only echo profile).
    """
    box = SceneBox(min=(-0.1, -0.1, 0.0), max=(0.1, 0.1, 0.2))
    meta = SurveyMeta(platform="sphere-test", scene_box=box, fs=100e3, sound_speed=343.0)
    ang = np.linspace(0, 2 * np.pi, n_pings, endpoint=False)
    h = np.linspace(0.02, 0.2, n_pings)
    tx = np.stack([ring * np.cos(ang), ring * np.sin(ang), h], 1)
    rx = np.stack([(ring + 0.013) * np.cos(ang), (ring + 0.013) * np.sin(ang), h - 0.038], 1)
    c = meta.sound_speed
    t0 = np.full(n_pings, 0.75 / c)
    t = t0[:, None] + np.arange(samples)[None] / meta.fs
    nrm = fibonacci_sphere(n_points)
    pts = np.asarray(center) + radius * nrm
    da = 4 * np.pi * radius**2 / n_points
    fc, bw = meta.pulse.f_center, meta.pulse.bandwidth
    sig = np.zeros((n_pings, samples), np.complex128)
    for n in range(n_pings):
        vt, vr = tx[n] - pts, rx[n] - pts
        rt, rr = np.linalg.norm(vt, axis=1), np.linalg.norm(vr, axis=1)
        cos_t = np.einsum("pi,pi->p", nrm, vt) / rt
        cos_r = np.einsum("pi,pi->p", nrm, vr) / rr
        vis = (cos_t > 0) & (cos_r > 0)
        a = da * cos_t[vis] / (rt[vis] * rr[vis])
        tau = (rt[vis] + rr[vis]) / c
        dt = t[n][None, :] - tau[:, None]
        if coherent:
            kern = np.exp(2j * np.pi * fc * dt) * np.sinc(bw * dt)
        else:
            kern = np.exp(-0.5 * (2 * bw * dt) ** 2)
        sig[n] = (a[:, None] * kern).sum(0)
    survey = Survey(tx=tx, rx=rx, samples=np.real(sig).astype(np.float32), t0=t0, meta=meta,
                    pulse=default_pulse(meta))
    return survey, (sig / np.abs(sig).max()).astype(np.complex64)


def density_concentration(field, center, radius, box, n: int = 40, shell: float = 0.01) -> float:
    """Mean density within ``shell`` m of the sphere surface over the mean density in the free
    space more than ``shell`` outside it (grid of ``n``^3 points over the box). The interior is
    left out: it is occluded by the front surface, so the data says nothing about it."""
    import torch

    axes = [np.linspace(lo, hi, n) for lo, hi in zip(box.min, box.max, strict=True)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    with torch.no_grad():
        p = next(field.parameters())
        rho = field.density(torch.as_tensor(g, dtype=p.dtype, device=p.device)).cpu().numpy()
    dist = np.linalg.norm(g - np.asarray(center), axis=1) - radius
    near, outside = np.abs(dist) < shell, dist >= shell
    return float(rho[near].mean() / max(rho[outside].mean(), 1e-30))
