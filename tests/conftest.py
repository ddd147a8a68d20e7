"""Shared fixtures: small valid surveys built in code, and the device option."""

from __future__ import annotations

import json
import os
import resource
import time
from collections.abc import Generator
from pathlib import Path
from typing import IO

import numpy as np
import pytest
import torch

from shsas_core.data.survey import Survey, SurveyMeta, default_pulse
from tests.schedule import order_items


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--device", default="cpu", help="torch device for device-parametrised tests")


@pytest.fixture
def device(request: pytest.FixtureRequest) -> torch.device:
    name = request.config.getoption("--device")
    if name.startswith("cuda") and not torch.cuda.is_available():
        pytest.skip("CUDA not available")
    return torch.device(name)


_CPU_REPORT_ENV = "SHSAS_TEST_CPU_REPORT"
_cpu_report: IO[str] | None = None


def _cpu_seconds() -> tuple[float, float]:
    """(this process's CPU s, reaped children's user+system CPU s)."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), ch.ru_utime + ch.ru_stime


def pytest_sessionstart(session: pytest.Session) -> None:
    global _cpu_report
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        # pytest-xdist's workers share the CPUs: a torch pool per worker sized for the whole
        # machine makes OpenMP threads spin for CPUs the other workers hold
        from shsas_core.common.threads import owned_cpus

        torch.set_num_threads(max(1, owned_cpus() // workers))
    path = os.environ.get(_CPU_REPORT_ENV)
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if path and worker:
        path = f"{path}.{worker}"  # one file per xdist worker (gw0, gw1, ...)
    if path:
        # one JSON line per test, flushed as it finishes, so a partial run is still readable
        _cpu_report = open(path, "w", encoding="utf-8")


def pytest_sessionfinish(session: pytest.Session) -> None:
    global _cpu_report
    if _cpu_report is not None:
        _cpu_report.close()
        _cpu_report = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None, None, None]:
    """Per test (setup + call + teardown): CPU seconds here and in reaped children, and wall seconds.

    Children's CPU counts only once they are waited for, so a server started by a module fixture
    shows up on the test whose teardown stops it.
    """
    if _cpu_report is None:
        yield
        return
    cpu0, ch0 = _cpu_seconds()
    wall0 = time.perf_counter()
    yield
    cpu1, ch1 = _cpu_seconds()
    rec = {
        "test": item.nodeid,
        "cpu_s": round(cpu1 - cpu0, 3),
        "children_cpu_s": round(ch1 - ch0, 3),
        "wall_s": round(time.perf_counter() - wall0, 3),
    }
    _cpu_report.write(json.dumps(rec) + "\n")
    _cpu_report.flush()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    order_items(items)
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


@pytest.fixture(scope="session")
def airsas_cutout() -> tuple[Survey, np.ndarray, float]:
    """The public AirSAS cut-out scan (``shared/data/airsas``, read in place) with its background
    removed: (survey, deconvolved signals, height of its plane of best focus under the nominal
    geometry). Built once per session: several modules read it, and the focus search alone costs
    seconds."""
    d = shared_dir()
    root = None if d is None else d / "data" / "airsas"
    if root is None or not (root / "cutout_20k").is_dir() or not (root / "bg_20k").is_dir():
        pytest.skip("../shared/data/airsas/cutout_20k is not beside the checkout")
    from shsas_core.formats import load_survey
    from shsas_core.imaging.planar import focus_height
    from shsas_core.signal.deconv import deconvolve

    s = load_survey(root / "cutout_20k", background=root / "bg_20k")
    sig = deconvolve(s)
    return s, sig, focus_height(s, sig)
