"""Real spherical harmonics up to degree 3, from sphericart-torch.

Convention (sphericart, identical to Wikipedia's "real spherical harmonics"): orthonormal on the
unit sphere, ∫ Y_lm Y_l'm' dΩ = δ_ll' δ_mm'; built from the complex Y_l^m that include the
Condon-Shortley phase (scipy's ``sph_harm_y``) as

    Y_lm = √2 (-1)^m Im Y_l^{|m|}   (m < 0)
    Y_l0 = Y_l^0
    Y_lm = √2 (-1)^m Re Y_l^m       (m > 0)

so that Y_1,-1 ∝ y, Y_1,0 ∝ z, Y_1,1 ∝ x (all with positive sign). Columns are ordered
l-major, m = -l..l: column index ``l^2 + l + m``; (L+1)^2 columns for degree L.

On CUDA, sphericart-torch's kernels load the CUDA 12 runtime compiler (``libnvrtc.so.12``) at
first use; on a machine with only CUDA 13 (the CUDA builds of torch >= 2.10) that load fails.
There :func:`sh_basis` falls back, with one warning, to :func:`sh_closed_form`: the same 16
polynomials written out in torch (checked against sphericart and scipy in tests/core/neural/test_sh.py).
"""

from __future__ import annotations

import logging
import math

import torch

from shsas_core.common.errors import ShsasError

MAX_DEGREE = 3

_CALCULATORS: dict[int, torch.nn.Module] = {}
#: Whether sphericart's CUDA kernels load on this machine (None: not tried yet).
_SPHERICART_CUDA: bool | None = None

log = logging.getLogger(__name__)


def num_coefficients(degree: int) -> int:
    """(L+1)^2: the number of real SH functions up to degree L."""
    return (degree + 1) ** 2


def sh_index(l: int, m: int) -> int:  # noqa: E741 (l is the conventional name)
    """Column of Y_lm in :func:`sh_basis` output."""
    return l * l + l + m


def _calculator(degree: int) -> torch.nn.Module:
    if degree not in _CALCULATORS:
        import sphericart.torch as sct

        _CALCULATORS[degree] = sct.SphericalHarmonics(degree)
    return _CALCULATORS[degree]


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Real orthonormal spherical harmonics of unit directions.

    Args:
        dirs: (P, 3) directions (x, y, z); normalised internally by sphericart, so only the
            direction matters (a zero vector gives NaN for l >= 1). float32 or float64, CPU or
            CUDA; differentiable (twice) in dirs.
        degree: L in 0..3.

    Returns:
        (P, (L+1)^2) values, column ``l^2 + l + m``.
    """
    if not isinstance(degree, int) or not 0 <= degree <= MAX_DEGREE:
        raise ShsasError(f"sh_basis: degree must be an integer in 0..{MAX_DEGREE}, got {degree!r}")
    if dirs.ndim != 2 or dirs.shape[1] != 3:
        raise ShsasError(f"sh_basis: dirs must have shape (P, 3), got {tuple(dirs.shape)}")
    if dirs.shape[0] == 0:
        return dirs.new_zeros(0, num_coefficients(degree))
    if dirs.is_cuda and not _sphericart_cuda_loads(dirs.device):
        return sh_closed_form(dirs, degree)
    return _calculator(degree)(dirs.contiguous())


def _sphericart_cuda_loads(device: torch.device) -> bool:
    global _SPHERICART_CUDA
    if _SPHERICART_CUDA is None:
        try:
            _calculator(0)(torch.ones(1, 3, device=device))
            _SPHERICART_CUDA = True
        except (RuntimeError, OSError) as exc:  # its CUDA library or one it needs did not load
            log.warning("sphericart's CUDA kernels did not load (%s); real spherical harmonics "
                        "on CUDA use the closed-form torch polynomials", str(exc).splitlines()[0][:200])
            _SPHERICART_CUDA = False
    return _SPHERICART_CUDA


_C0 = 0.5 * math.sqrt(1 / math.pi)
_C1 = math.sqrt(3 / (4 * math.pi))
_C2 = (0.5 * math.sqrt(15 / math.pi), 0.25 * math.sqrt(5 / math.pi), 0.25 * math.sqrt(15 / math.pi))
_C3 = (0.25 * math.sqrt(35 / (2 * math.pi)), 0.5 * math.sqrt(105 / math.pi),
       0.25 * math.sqrt(21 / (2 * math.pi)), 0.25 * math.sqrt(7 / math.pi), 0.25 * math.sqrt(105 / math.pi))


def sh_closed_form(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """The basis of :func:`sh_basis` as explicit polynomials of the unit direction, in torch ops
    (any device, any float dtype, differentiable to any order).

    Args:
        dirs: (P, 3) directions, normalised here (a zero vector gives NaN for l >= 1).
        degree: L in 0..3 (not validated: :func:`sh_basis` does that).
    Returns:
        (P, (L+1)^2) values, column ``l^2 + l + m``.
    """
    u = dirs / torch.linalg.vector_norm(dirs, dim=1, keepdim=True)
    x, y, z = u[:, 0], u[:, 1], u[:, 2]
    cols = [torch.full_like(x, _C0)]
    if degree >= 1:
        cols += [_C1 * y, _C1 * z, _C1 * x]
    if degree >= 2:
        a, b, c = _C2
        cols += [a * x * y, a * y * z, b * (3 * z * z - 1), a * x * z, c * (x * x - y * y)]
    if degree >= 3:
        a, b, c, d, e = _C3
        zz = 5 * z * z - 1
        cols += [a * y * (3 * x * x - y * y), b * x * y * z, c * y * zz, d * z * (5 * z * z - 3),
                 c * x * zz, e * z * (x * x - y * y), a * x * (x * x - 3 * y * y)]
    return torch.stack(cols, 1)


def angular_roughness(coeffs: torch.Tensor) -> torch.Tensor:
    """Dirichlet energy on the sphere of ``σ(ω) = Σ c_lm Y_lm(ω)``: ``∫ |∇_S σ|² dω = Σ l(l+1) |c_lm|²``.

    The Y_lm are orthonormal eigenfunctions of the Laplace–Beltrami operator with eigenvalue
    −l(l+1), so the integral of the squared surface gradient is this weighted sum: 0 for an
    isotropic σ, and 6x, 3x, 2x dearer per unit energy at degree 3 than at 1. Per point, so a
    caller chooses how to weight points.

    Args:
        coeffs: (P, (L+1)^2) real or complex coefficients, column ``l^2 + l + m``.
    Returns:
        (P,) real, >= 0, in the squared units of the coefficients (times sr⁰: the Y_lm are
        dimensionless on the unit sphere).
    """
    degree = math.isqrt(coeffs.shape[-1]) - 1 if coeffs.ndim == 2 else -1
    if degree < 0 or num_coefficients(degree) != coeffs.shape[-1]:
        raise ShsasError(f"angular_roughness: coeffs must have shape (P, (L+1)^2), got {tuple(coeffs.shape)}")
    # column l^2 + l + m has degree l = floor(sqrt(column))
    l = torch.arange(coeffs.shape[-1], device=coeffs.device).float().sqrt().floor()  # noqa: E741
    weight = (l * (l + 1)).to(coeffs.real.dtype)
    # re² + im² rather than |c|²: smooth at c = 0, where |c| has no derivative
    power = coeffs.real.pow(2) + coeffs.imag.pow(2) if coeffs.is_complex() else coeffs.pow(2)
    return (power * weight).sum(-1)
