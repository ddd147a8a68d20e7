"""Constant time-of-flight ellipsoids and their intersection with transmitter rays.

A two-way path length ``r = |x - o_T| + |x - o_R|`` (metres) defines an ellipsoid of revolution
with foci ``o_T`` and ``o_R``: semi-major axis ``a = r / 2`` along the baseline, the two other
semi-axes ``b = sqrt(a^2 - d^2 / 4)`` with ``d = |o_T - o_R|`` (paper supplement, "Ellipsoidal
Sampling"). Bins with ``a <= d / 2`` (``r <= d``, before the direct path) have no surface and are
marked invalid.

Two intersection routines give the same answer:

* :func:`intersect_quadric` follows the supplement literally: rotate the ray into the ellipsoid's
  frame, solve the quadratic, keep the smallest positive root. It is the reference.
* :func:`intersect_focal` uses the fact that the ray starts at a focus: substituting
  ``x = o_T + l u`` into ``l + |x - o_R| = r`` gives the single positive root
  ``l = (r^2 - d^2) / (2 (r + u . (o_T - o_R)))``. No rotation, no square root, no cancellation
  when ``d -> 0``; it is what the renderer uses.

All tensors are torch, any float dtype, on any device. Shapes: ``B`` pings, ``K`` bins per ping,
``M`` rays per ping.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: Bins whose two-way path exceeds the baseline by less than this (m) are treated as degenerate.
DEGENERATE_EPS = 1e-9


def ellipsoid_frame(tx: Tensor, rx: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Centre, rotation and focal separation of the TX/RX ellipsoids.

    Args:
        tx, rx: (B, 3) transmitter and receiver positions, m.

    Returns:
        m: (B, 3) midpoint of the foci, m.
        R: (B, 3, 3) rotation whose columns are the frame axes, ``R^T (rx - tx) = (d, 0, 0)``.
            For a monostatic ping (d = 0) the ellipsoid is a sphere and any frame is valid; the
            world x axis is used.
        d: (B,) focal separation ``|tx - rx|``, m.
    """
    m = 0.5 * (tx + rx)
    v = rx - tx
    d = v.norm(dim=-1)
    ex = torch.zeros_like(v)
    ex[..., 0] = 1.0
    e1 = torch.where((d > DEGENERATE_EPS)[..., None], v / d.clamp_min(DEGENERATE_EPS)[..., None], ex)
    helper = torch.zeros_like(v)
    use_y = e1[..., 2].abs() > 0.9  # avoid a helper nearly parallel to e1
    helper[..., 2] = torch.where(use_y, 0.0, 1.0).to(v.dtype)
    helper[..., 1] = torch.where(use_y, 1.0, 0.0).to(v.dtype)
    e2 = torch.linalg.cross(helper, e1)
    e2 = e2 / e2.norm(dim=-1, keepdim=True)
    e3 = torch.linalg.cross(e1, e2)
    R = torch.stack([e1, e2, e3], dim=-1)
    return m, R, d


def intersect_quadric(tx: Tensor, rx: Tensor, dirs: Tensor, radii: Tensor) -> tuple[Tensor, Tensor]:
    """Reference ray-ellipsoid intersection in the ellipsoid frame (paper supplement).

    Args:
        tx, rx: (B, 3) positions, m.
        dirs: (B, M, 3) unit ray directions from ``tx``.
        radii: (B, K) two-way path lengths ``r`` of the bins, m.

    Returns:
        l: (B, K, M) distance along each ray to the smallest positive root, m (0 where invalid).
        valid: (B, K, M) bool, False for ``a <= d/2``, no real root or no positive root.
    """
    m, R, d = ellipsoid_frame(tx, rx)
    o = torch.einsum("bji,bj->bi", R, tx - m)  # (B,3) = (-d/2, 0, 0) up to rounding
    u = torch.einsum("bji,bmj->bmi", R, dirs)  # (B,M,3) ray directions in the frame
    a = 0.5 * radii  # (B,K)
    b2 = a * a - 0.25 * (d * d)[:, None]
    ok_bin = b2 > DEGENERATE_EPS * a.clamp_min(1.0)
    a2 = (a * a)[..., None]
    b2s = torch.where(ok_bin, b2, torch.ones_like(b2))[..., None]
    ux, uy, uz = u[:, None, :, 0], u[:, None, :, 1], u[:, None, :, 2]
    ox, oy, oz = (o[:, 0][:, None, None], o[:, 1][:, None, None], o[:, 2][:, None, None])
    qa = ux * ux / a2 + (uy * uy + uz * uz) / b2s
    qb = 2.0 * (ox * ux / a2 + (oy * uy + oz * uz) / b2s)
    qc = ox * ox / a2 + (oy * oy + oz * oz) / b2s - 1.0
    disc = qb * qb - 4.0 * qa * qc
    sq = disc.clamp_min(0.0).sqrt()
    lm = (-qb - sq) / (2.0 * qa)
    lp = (-qb + sq) / (2.0 * qa)
    big = torch.full_like(lm, float("inf"))
    l_star = torch.minimum(torch.where(lm > 0, lm, big), torch.where(lp > 0, lp, big))
    valid = ok_bin[..., None] & (disc >= 0) & torch.isfinite(l_star)
    return torch.where(valid, l_star, torch.zeros_like(l_star)), valid


def intersect_focal(tx: Tensor, rx: Tensor, dirs: Tensor, radii: Tensor) -> tuple[Tensor, Tensor]:
    """Closed-form intersection of rays leaving the focus ``tx`` with the ellipsoids.

    Same arguments and returns as :func:`intersect_quadric`. Derivation: with ``v = tx - rx``,
    ``|v + l u|^2 = (r - l)^2`` is linear in ``l``; its root is positive iff ``r > d`` because
    ``r + u.v >= r - d``. ``l`` grows monotonically with ``r`` along a ray
    (``dl/dr ∝ |r u + v|^2 >= 0``), so bins sorted by radius give samples sorted along the ray.
    """
    v = tx - rx
    d = v.norm(dim=-1)  # (B,)
    uv = torch.einsum("bmi,bi->bm", dirs, v)  # (B,M)
    r = radii[..., None]  # (B,K,1)
    ok_bin = radii - d[:, None] > DEGENERATE_EPS  # (B,K)
    den = 2.0 * (r + uv[:, None, :])
    num = r * r - (d * d)[:, None, None]
    valid = ok_bin[..., None] & (den > 0)
    dist = torch.where(valid, num / torch.where(valid, den, torch.ones_like(den)), torch.zeros_like(den))
    return dist, valid.expand_as(dist)


def points_on_rays(tx: Tensor, dirs: Tensor, dist: Tensor) -> Tensor:
    """Sample positions ``x = tx + dist u``: (B,3), (B,M,3), (B,K,M) -> (B,K,M,3) m."""
    return tx[:, None, None, :] + dist[..., None] * dirs[:, None, :, :]


def area_jacobian(tx: Tensor, rx: Tensor, x: Tensor, dirs: Tensor) -> Tensor:
    """Spherical-spreading weight per unit TX solid angle, ``R_T / (R_R cos psi)``.

    A surface element ``dA`` of the ellipsoid seen from the TX under solid angle ``dOmega`` has
    ``dA = R_T^2 dOmega / cos psi`` where ``psi`` is the angle between the ray and the ellipsoid
    normal. The normal is the bisector of the unit vectors from both foci, so
    ``cos psi = sqrt((1 + u . w) / 2)`` with ``w = (x - rx) / R_R``. A point scatterer's echo
    amplitude falls as ``1 / (R_T R_R)``, so its contribution per ``dOmega`` is
    ``R_T / (R_R cos psi)``: exactly 1 for a monostatic ping.

    Args:
        tx, rx: (B, 3) m; x: (B, K, M, 3) points m; dirs: (B, M, 3) unit rays.
    Returns:
        (B, K, M) dimensionless weight (cos psi clamped at 1e-3 for grazing rays).
    """
    rt = (x - tx[:, None, None, :]).norm(dim=-1)
    wv = x - rx[:, None, None, :]
    rr = wv.norm(dim=-1).clamp_min(1e-12)
    cos_uw = (wv * dirs[:, None, :, :]).sum(-1) / rr
    cos_psi = (0.5 * (1.0 + cos_uw)).clamp_min(1e-6).sqrt().clamp_min(1e-3)
    return rt / (rr * cos_psi)
