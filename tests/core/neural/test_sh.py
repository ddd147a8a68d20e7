"""Real SH basis: orthonormality by exact quadrature, equality with scipy, derivatives."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.special import roots_legendre, sph_harm_y

from shsas_core.common.errors import ShsasError
from shsas_core.neural.fields.sh import (
    angular_roughness,
    num_coefficients,
    sh_basis,
    sh_closed_form,
    sh_index,
)


def _dirs(theta: np.ndarray, phi: np.ndarray) -> torch.Tensor:
    st = np.sin(theta)
    return torch.from_numpy(np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], 1))


def _scipy_real(l: int, m: int, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:  # noqa: E741
    """Real SH from scipy's complex ones (Condon-Shortley phase), standard (Wikipedia) signs."""
    y = sph_harm_y(l, abs(m), theta, phi)
    if m < 0:
        return np.sqrt(2) * (-1) ** m * y.imag
    if m > 0:
        return np.sqrt(2) * (-1) ** m * y.real
    return y.real


def test_orthonormal_by_gauss_legendre_product_quadrature() -> None:
    # Products Y_lm Y_l'm' (l, l' <= 3) are polynomials of degree <= 6 on the sphere: an 8-node
    # Gauss-Legendre rule in cos θ (exact to degree 15) times 16 equispaced φ (exact for
    # trigonometric degree <= 15) integrates them exactly, so the Gram matrix must be the
    # identity to rounding (1e-12), not to a Monte-Carlo tolerance.
    xg, wg = roots_legendre(8)
    phi = np.arange(16) * 2 * np.pi / 16
    ct, ph = np.meshgrid(xg, phi, indexing="ij")
    w = (wg[:, None] * np.full(16, 2 * np.pi / 16)[None, :]).ravel()
    y = sh_basis(_dirs(np.arccos(ct.ravel()), ph.ravel()), 3).numpy()
    gram = (y * w[:, None]).T @ y
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-12)


def test_orthonormal_on_fibonacci_lattice() -> None:
    # Independent check with equal-area points (an equal-weight quasi-Monte-Carlo rule): for these
    # smooth (degree <= 6 polynomial) integrands the error is far below the 1/n = 5e-5 scale
    # (measured 4e-6 at n = 20 000); 1e-4 leaves margin, while a wrong normalisation (4π,
    # Schmidt) or a wrong sign/ordering would be off by >= 0.1.
    n = 20_000
    i = np.arange(n) + 0.5
    theta = np.arccos(1 - 2 * i / n)
    phi = (np.pi * (1 + 5**0.5) * i) % (2 * np.pi)
    y = sh_basis(_dirs(theta, phi), 3).numpy()
    gram = y.T @ y * (4 * np.pi / n)
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-4)


def test_equals_scipy_up_to_degree_3() -> None:
    rng = np.random.default_rng(0)
    theta = np.arccos(rng.uniform(-1, 1, 200))
    phi = rng.uniform(0, 2 * np.pi, 200)
    for degree in range(4):
        y = sh_basis(_dirs(theta, phi), degree).numpy()
        assert y.shape == (200, num_coefficients(degree))
        for l in range(degree + 1):  # noqa: E741
            for m in range(-l, l + 1):
                np.testing.assert_allclose(y[:, sh_index(l, m)], _scipy_real(l, m, theta, phi), atol=1e-12)


def test_degree_one_signs_and_scale_invariance() -> None:
    d = torch.tensor([[0.3, -0.4, 0.5]], dtype=torch.float64)
    y = sh_basis(d, 1)[0]
    c = np.sqrt(3 / (4 * np.pi)) / float(d.norm())
    torch.testing.assert_close(y[1:], torch.tensor([-0.4 * c, 0.5 * c, 0.3 * c], dtype=torch.float64))
    torch.testing.assert_close(sh_basis(7 * d, 3), sh_basis(d, 3))


def test_gradcheck_dirs() -> None:
    d = torch.randn(6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: sh_basis(v, 3), (d,))


def test_bad_input() -> None:
    with pytest.raises(ShsasError, match="degree"):
        sh_basis(torch.randn(3, 3), 4)
    with pytest.raises(ShsasError, match=r"\(P, 3\)"):
        sh_basis(torch.randn(3, 2), 1)
    assert sh_basis(torch.zeros(0, 3), 2).shape == (0, 9)


def test_closed_form_equals_sphericart_and_is_differentiable() -> None:
    # the CUDA fallback (sphericart's CUDA kernels need CUDA 12's nvrtc): same values as the
    # sphericart basis the other tests check against scipy, for every degree
    d = torch.randn(300, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 3
    for degree in range(4):
        torch.testing.assert_close(sh_closed_form(d, degree), sh_basis(d, degree), rtol=0, atol=1e-12)
    v = d[:5].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda w: sh_closed_form(w, 3), (v,))
    assert torch.autograd.gradgradcheck(lambda w: sh_closed_form(w, 3), (v,))


@pytest.mark.gpu
def test_cuda_basis_matches_cpu() -> None:
    d = torch.randn(1000, 3, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(sh_basis(d.cuda(), 3).cpu(), sh_basis(d, 3), rtol=1e-5, atol=1e-6)


def test_angular_roughness_is_the_dirichlet_energy_by_quadrature() -> None:
    # ∫ |∇_S σ|² dΩ with ∇_S σ = (∂σ/∂θ, ∂σ/∂φ / sin θ), the derivatives by autograd through the
    # closed-form basis of the angles, integrated by a Gauss-Legendre rule in cos θ times
    # equispaced φ: an independent route to the eigenvalue identity Σ l(l+1) |c_lm|².
    g = torch.Generator().manual_seed(4)
    coeffs = torch.randn(3, 16, dtype=torch.float64, generator=g)
    xg, wg = roots_legendre(24)
    n_phi = 48
    ct, ph = np.meshgrid(xg, np.arange(n_phi) * 2 * np.pi / n_phi, indexing="ij")
    theta = torch.from_numpy(np.arccos(ct.ravel())).requires_grad_(True)
    phi = torch.from_numpy(ph.ravel()).requires_grad_(True)
    st = torch.sin(theta)
    y = sh_closed_form(torch.stack([st * torch.cos(phi), st * torch.sin(phi), torch.cos(theta)], 1), 3)
    w = torch.from_numpy((wg[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).ravel())
    for c in coeffs:
        sigma = y @ c
        d_theta, d_phi = torch.autograd.grad(sigma.sum(), (theta, phi), retain_graph=True)
        energy = (w * (d_theta**2 + (d_phi / st) ** 2)).sum()
        np.testing.assert_allclose(float(angular_roughness(c[None])[0]), float(energy.detach()), rtol=1e-9)


def test_angular_roughness_of_complex_coefficients_and_its_weights() -> None:
    # one unit coefficient per column: the weight l(l+1) of its degree; complex = real² + imag²
    eye = torch.eye(16, dtype=torch.float64)
    expected = torch.tensor([d * (d + 1) for d in range(4) for _ in range(2 * d + 1)], dtype=torch.float64)
    torch.testing.assert_close(angular_roughness(eye), expected)
    c = torch.complex(eye, 2 * eye)
    torch.testing.assert_close(angular_roughness(c), 5 * expected)
    assert float(angular_roughness(torch.ones(5, 1))[0]) == 0.0  # L = 0: isotropic
    with pytest.raises(ShsasError, match=r"\(P, \(L\+1\)\^2\)"):
        angular_roughness(torch.ones(4, 5))


def test_angular_roughness_gradcheck() -> None:
    c = torch.complex(torch.randn(4, 9, dtype=torch.float64), torch.randn(4, 9, dtype=torch.float64))
    assert torch.autograd.gradcheck(angular_roughness, (c.requires_grad_(True),))
    zero = torch.zeros(2, 9, dtype=torch.complex128, requires_grad=True)
    (g,) = torch.autograd.grad(angular_roughness(zero).sum(), zero)
    assert torch.isfinite(torch.view_as_real(g)).all()
