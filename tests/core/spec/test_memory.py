"""Declared sizes are checked before any samples are read, and the reading of the samples
honours cancel. Real HDF5 files; see tests/declared_size.py."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from shsas_core.common.errors import Cancelled, SurveyValidationError
from shsas_core.formats.hdf5 import READ_BLOCK_BYTES, read_survey
from shsas_core.pipeline.job import run
from shsas_core.spec.job import ReconstructionSpec
from shsas_core.spec.memory import (
    GiB,
    MemoryBudgetError,
    check_job_memory,
    default_memory_budget,
    job_memory_bytes,
    machine_memory_bytes,
)
from tests.helpers.declared_size import unwritten_samples, zero_filled_samples

QUICK = ReconstructionSpec(methods=["backprojection"], grid=16, device="cpu")
SHAPE = (64, 500_000)  # 128 MB of float32 samples: two read blocks


@pytest.fixture(scope="module")
def zeros(tmp_path_factory) -> Path:
    return zero_filled_samples(tmp_path_factory.mktemp("mem") / "zeros.h5", *SHAPE)


def test_never_written_samples_are_refused_from_the_header(tmp_path: Path) -> None:
    path = unwritten_samples(tmp_path / "u.h5", 360, 1_000_000)
    assert path.stat().st_size < 1_000_000
    with pytest.raises(SurveyValidationError, match=r"pings/samples: declares shape \(360, 1000000\).*never written"):
        read_survey(path, load_samples=False)


def test_estimate_grows_with_the_job_and_the_default_budget_fits_the_machine(zeros: Path) -> None:
    header = read_survey(zeros, load_samples=False)
    small = job_memory_bytes(header, QUICK)
    assert small > SHAPE[0] * SHAPE[1] * 4  # at least the samples themselves
    assert job_memory_bytes(header, QUICK.model_copy(update={"grid": 256})) > small
    assert job_memory_bytes(header, QUICK.model_copy(update={"methods": ["backprojection", "reed"]})) > small
    assert 0 < default_memory_budget() < machine_memory_bytes()
    assert check_job_memory(header, QUICK, 64 * GiB) == small
    with pytest.raises(MemoryBudgetError, match=r"64 pings x 500000 samples .* budget of 1\.0 GiB"):
        check_job_memory(header, QUICK, 1 * GiB)


def test_estimate_counts_the_ground_truth_mesh_and_loaded_extras(zeros: Path) -> None:
    """A small survey with a large mesh is not a small job: each vertex and face counts."""
    import dataclasses

    from shsas_core.spec.memory import GROUND_TRUTH_ELEMENT_BYTES

    header = read_survey(zeros, load_samples=False)
    verts, faces = np.zeros((3_000_000, 3)), np.zeros((6_000_000, 3), np.int64)
    meshed = dataclasses.replace(header, gt_vertices=verts, gt_faces=faces)
    plain = job_memory_bytes(header, QUICK)
    assert job_memory_bytes(meshed, QUICK) - plain == 9_000_000 * GROUND_TRUTH_ELEMENT_BYTES
    # at least what the arrays themselves hold
    assert job_memory_bytes(meshed, QUICK) - plain >= verts.nbytes + faces.nbytes
    extra = dataclasses.replace(header, extras={"deconvolved": np.zeros((64, 1000), np.float32)})
    assert job_memory_bytes(extra, QUICK) - plain == 64 * 1000 * 4
    budget = plain + GiB // 2
    assert check_job_memory(header, QUICK, budget) == plain
    with pytest.raises(MemoryBudgetError, match="ground-truth mesh of 9000000 vertices and faces"):
        check_job_memory(meshed, QUICK, budget)


class StopAfter:
    """A should_stop that counts its calls and says stop from call ``n`` on (None: never)."""

    def __init__(self, n: int | None = None):
        self.n, self.calls = n, 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.n is not None and self.calls >= self.n


def test_samples_are_read_in_blocks_and_a_cancel_stops_the_read(zeros: Path) -> None:
    count = StopAfter()
    survey = read_survey(zeros, should_stop=count)
    rows = READ_BLOCK_BYTES // (SHAPE[1] * 4)
    assert count.calls == math.ceil(SHAPE[0] / rows) >= 2
    assert survey.samples.dtype == np.float32 and survey.samples.shape == SHAPE
    stop = StopAfter(2)
    with pytest.raises(Cancelled):
        read_survey(zeros, should_stop=stop)
    assert stop.calls == 2


def test_pipeline_checks_the_budget_before_loading_and_cancels_while_loading(zeros: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(MemoryBudgetError, match="budget of 1.0 GiB"):
        run(QUICK, zeros, out, memory_budget=1 * GiB)
    assert not out.exists()
    stages: list[str] = []
    with pytest.raises(Cancelled):
        run(QUICK, zeros, out, progress=lambda f, stage, m: stages.append(stage), should_stop=lambda: True)
    assert stages == ["load"] and not out.exists()
