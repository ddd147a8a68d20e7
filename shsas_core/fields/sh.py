"""Real spherical harmonics up to degree 3, from sphericart-torch.

Convention (sphericart, identical to Wikipedia's "real spherical harmonics"): orthonormal on the
unit sphere, ∫ Y_lm Y_l'm' dΩ = δ_ll' δ_mm'; built from the complex Y_l^m that include the
Condon-Shortley phase (scipy's ``sph_harm_y``) as

    Y_lm = √2 (-1)^m Im Y_l^{|m|}   (m < 0)
    Y_l0 = Y_l^0
    Y_lm = √2 (-1)^m Re Y_l^m       (m > 0)

so that Y_1,-1 ∝ y, Y_1,0 ∝ z, Y_1,1 ∝ x (all with positive sign). Columns are ordered
l-major, m = -l..l: column index ``l^2 + l + m``; (L+1)^2 columns for degree L.
"""

from __future__ import annotations

import torch

from ..errors import ShsasError

MAX_DEGREE = 3

_CALCULATORS: dict[int, torch.nn.Module] = {}


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
    return _calculator(degree)(dirs.contiguous())
