"""The cost cap and the per-key quota: which specs pass the default limits,
and what a refusal says. The HTTP answers (422, 429) are in test_operations.py."""

from __future__ import annotations

import pytest

from jobs.settings import Settings
from service.quotas import (
    check_active_jobs,
    check_cpu_time,
    check_spec_cost,
    max_grid,
    train_samples,
)
from service.uploads import UploadError
from shsas_core.data.survey import SceneBox
from shsas_core.spec.job import PRESETS, ReconstructionSpec

from .test_celery import LONG_SPEC, RESUMABLE_SPEC
from .test_embedded import QUICK_SPEC
from .test_redis_loss import BLOCKER_SPEC

#: The issue's example of a spec that was accepted: hours of GPU time per job.
HUGE = {"grid": 512, "num_rays": 65536, "num_bins": 4096, "iters": 200_000}


@pytest.mark.parametrize("spec", [
    {},  # the project's default spec, which `shsas demo` runs too
    PRESETS["paper"], QUICK_SPEC, LONG_SPEC, RESUMABLE_SPEC, BLOCKER_SPEC,
    {**LONG_SPEC, "iters": 200_000},  # benchmarks/bench_service.py
    {"grid": 512, "methods": ["backprojection"]},  # the largest grid the spec allows
], ids=["default", "paper", "quick", "long", "resumable", "blocker", "bench", "grid512"])
def test_default_limits_accept_the_projects_specs(spec: dict) -> None:
    settings = Settings()
    check_spec_cost(ReconstructionSpec.model_validate(spec), settings, SceneBox(min=(-1, -1, 0), max=(1, 1, 1)))


def test_cost_cap_names_the_limit() -> None:
    with pytest.raises(UploadError) as err:
        check_spec_cost(ReconstructionSpec.model_validate(HUGE), Settings())
    assert err.value.status == 422
    assert "SHSAS_MAX_TRAIN_SAMPLES" in err.value.message and "5.37e+13" in err.value.message
    assert train_samples(ReconstructionSpec(methods=["backprojection"], iters=200_000)) == 0


def test_grid_cap_checks_the_explicit_and_the_automatic_grid() -> None:
    settings = Settings(max_grid_voxels=64**3)
    check_spec_cost(ReconstructionSpec(grid=64), settings)
    with pytest.raises(UploadError) as err:
        check_spec_cost(ReconstructionSpec(grid=65), settings)
    assert err.value.status == 422 and "spec.grid: 65^3" in err.value.message
    assert "SHSAS_MAX_GRID_VOXELS: grid 64 at most" in err.value.message
    check_spec_cost(ReconstructionSpec(), settings)  # automatic grid: unknown before the survey is read
    with pytest.raises(UploadError) as err:  # a 0.25 m box at 2.5 mm voxels: grid 100
        check_spec_cost(ReconstructionSpec(), settings, SceneBox())
    assert "automatic" in err.value.message and "100^3" in err.value.message
    assert [max_grid(n) for n in (512**3, 512**3 - 1, 100)] == [512, 511, 4]


def test_cpu_cap_refuses_days_on_a_cpu_with_the_estimate_and_only_on_the_cpu_queue() -> None:
    settings = Settings()  # the cap defaults to the 6 h job time limit
    paper_on_cpu = ReconstructionSpec.model_validate({**PRESETS["paper"], "device": "cpu"})
    with pytest.raises(UploadError) as err:
        check_cpu_time(paper_on_cpu, settings)
    assert err.value.status == 422 and "SHSAS_MAX_CPU_JOB_S" in err.value.message
    n_neural = sum(m in ("reed", "shsas") for m in paper_on_cpu.methods)
    hours = n_neural * 50_000 * 960_000 / 6e5 / 3600  # iterations x samples each / samples per s
    assert f"training {hours:.1f} h" in err.value.message
    check_cpu_time(paper_on_cpu.model_copy(update={"device": "cuda"}), settings)  # a GPU job: not capped
    for spec in (QUICK_SPEC, LONG_SPEC, RESUMABLE_SPEC, BLOCKER_SPEC, {**LONG_SPEC, "iters": 200_000}):
        check_cpu_time(ReconstructionSpec.model_validate({**spec, "device": "cpu"}), settings)
    tight = Settings(max_cpu_job_s=60)
    with pytest.raises(UploadError, match="backprojection"):  # known once the survey is validated
        check_cpu_time(ReconstructionSpec(methods=["backprojection"], grid=256, device="cpu"), tight,
                       {"pings": 2000, "samples_per_ping": 1000})


def test_quota_is_429_naming_the_limit() -> None:
    settings = Settings(max_active_jobs_per_key=3)
    check_active_jobs(2, settings)
    with pytest.raises(UploadError) as err:
        check_active_jobs(3, settings)
    assert err.value.status == 429 and "SHSAS_MAX_ACTIVE_JOBS_PER_KEY" in err.value.message
    assert "the limit is 3" in err.value.message


# ---- the quota under concurrency: real `shsas serve`, real HTTP, SQLite and PostgreSQL -------

CONCURRENT_POSTS = 12
SMALL_QUOTA = 2


@pytest.mark.service
@pytest.mark.slow
@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_concurrent_submissions_of_one_key_get_at_most_the_quota(backend, tmp_path, request) -> None:
    """Twelve POSTs at once from one key with a quota of 2: two are accepted, the rest get 429.
    (The count used to be read before the seconds-long validation, so all of them passed it.)"""
    import concurrent.futures

    import httpx

    from .conftest import db_env, start_server, submit, write_tiny_survey

    pg = request.getfixturevalue("pg_url") if backend == "postgresql" else None
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), "SHSAS_MAX_ACTIVE_JOBS_PER_KEY": str(SMALL_QUOTA),
           **db_env(backend, pg)}
    survey = write_tiny_survey(tmp_path / "tiny.h5")
    proc, base = start_server(tmp_path, {**env}, name=f"quota-{backend}")
    try:
        # A long fit: the accepted jobs stay queued or running (both count) while the rest arrive.
        spec = {"methods": ["shsas"], "iters": 100000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}

        def post(_: int) -> int:
            with httpx.Client(base_url=base, timeout=300) as c:
                return submit(c, survey, spec).status_code

        with concurrent.futures.ThreadPoolExecutor(CONCURRENT_POSTS) as pool:
            codes = list(pool.map(post, range(CONCURRENT_POSTS)))
        assert sorted(set(codes)) == [202, 429], codes
        assert codes.count(202) == SMALL_QUOTA, codes
        with httpx.Client(base_url=base, timeout=60) as c:
            items = c.get("/reconstructions", params={"limit": 100}).json()["items"]
            assert len(items) == SMALL_QUOTA
            for job in items:  # free the worker for the next test
                c.post(f"/reconstructions/{job['id']}/cancel")
    finally:
        proc.stop()
