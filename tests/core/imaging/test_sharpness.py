"""Focus measures against independent references (scipy's entropy, a brute-force moment)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import entropy as scipy_entropy

from shsas_core.imaging.sharpness import focus_cost, image_contrast, image_entropy


def test_entropy_matches_scipy_on_a_random_complex_image():
    rng = np.random.default_rng(3)
    img = rng.standard_normal((17, 9)) + 1j * rng.standard_normal((17, 9))
    q = np.abs(img) ** 2
    assert image_entropy(img) == pytest.approx(scipy_entropy(q.ravel()), rel=1e-12)


def test_entropy_and_contrast_limits():
    flat = np.ones((8, 8))
    spike = np.zeros((8, 8))
    spike[3, 4] = 5.0
    assert image_entropy(flat) == pytest.approx(math.log(64))
    assert image_entropy(spike) == pytest.approx(0.0)
    assert image_contrast(flat) == pytest.approx(1.0)
    assert image_contrast(spike) == pytest.approx(64.0)
    # no energy: no focus (the flat image's values), not NaN
    assert image_entropy(np.zeros(5)) == pytest.approx(math.log(5))
    assert image_contrast(np.zeros(5)) == 0.0


def test_contrast_matches_a_brute_force_fourth_moment():
    rng = np.random.default_rng(4)
    img = rng.standard_normal(50) + 1j * rng.standard_normal(50)
    q = [abs(v) ** 2 for v in img]
    brute = len(q) * sum(v * v for v in q) / sum(q) ** 2
    assert image_contrast(img) == pytest.approx(brute, rel=1e-12)


@pytest.mark.parametrize("measure", ["entropy", "contrast"])
def test_cost_falls_as_an_image_sharpens(measure):
    x = np.linspace(-1, 1, 101)
    costs = [focus_cost(np.exp(-(x / w) ** 2), measure) for w in (0.5, 0.2, 0.05)]
    assert costs[0] > costs[1] > costs[2]
