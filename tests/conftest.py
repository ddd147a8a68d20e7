"""Shared fixtures: small valid surveys built in code, and the device option."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from shsas_core.data.survey import Survey, SurveyMeta, default_pulse


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--device", default="cpu", help="torch device for device-parametrised tests")


@pytest.fixture
def device(request: pytest.FixtureRequest) -> torch.device:
    name = request.config.getoption("--device")
    if name.startswith("cuda") and not torch.cuda.is_available():
        pytest.skip("CUDA not available")
    return torch.device(name)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs CUDA")
    for item in items:
        # the marker, not item.keywords: keywords also hold the names of the parent directories,
        # so a checkout in a directory named "gpu" would skip every test
        if item.get_closest_marker("gpu") is not None:
            item.add_marker(skip)


def circular_geometry(n: int, radius: float = 0.85, height: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """TX/RX on a circle around the origin with the AirSAS-like 13 mm / 38 mm offsets."""
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tx = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(n, height)], 1)
    rx = np.stack([(radius + 0.013) * np.cos(ang), (radius + 0.013) * np.sin(ang), np.full(n, height - 0.038)], 1)
    return tx, rx


def make_survey(n: int = 8, t: int = 512, complex_: bool = False, seed: int = 0, **meta_kw) -> Survey:
    """A small valid survey with random samples (not physically meaningful)."""
    rng = np.random.default_rng(seed)
    meta = SurveyMeta(platform="test", **meta_kw)
    tx, rx = circular_geometry(n)
    samples = rng.standard_normal((n, t)).astype(np.float32)
    if complex_:
        samples = (samples + 1j * rng.standard_normal((n, t))).astype(np.complex64)
        meta = meta.model_copy(update={"signal_kind": "analytic"})
    return Survey(tx=tx, rx=rx, samples=samples, t0=np.full(n, 3e-3), meta=meta, pulse=default_pulse(meta))


@pytest.fixture
def tiny_survey() -> Survey:
    return make_survey()


def shared_dir() -> Path | None:
    """The `shared/` folder beside the checkout (paper, meshes), or $SHSAS_SHARED; None if absent."""
    env = os.environ.get("SHSAS_SHARED")
    cands = [Path(env)] if env else []
    root = Path(__file__).resolve().parents[1]
    cands += [root.parent / "shared", root / "shared"]
    for c in cands:
        if (c / "data" / "meshes").is_dir():
            return c
    return None


@pytest.fixture
def shared() -> Path:
    d = shared_dir()
    if d is None:
        pytest.skip("../shared is not beside the checkout")
    return d
