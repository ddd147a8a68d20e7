"""Schema-driven fuzzing of the whole HTTP API with Schemathesis: no input gives a server error.

Every operation and parameter in the served OpenAPI schema (paths, query, headers, the
multipart upload) is generated, valid and invalid (Schemathesis' positive and negative
modes), and sent to a real `shsas serve` over HTTP; the only check is that nothing answers
5xx. A second test aims the generated artifact headers (Range, If-Range, If-None-Match) at a
real artifact, which random job ids never reach. Example counts are small so that the module
stays within about three minutes on two loaded cores (about one when they are idle).
"""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

schemathesis = pytest.importorskip("schemathesis")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.errors import Unsatisfiable  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402

from .conftest import start_server, submit, wait_for, write_tiny_survey  # noqa: E402

pytestmark = [pytest.mark.service, pytest.mark.slow]

#: Generated cases per operation, and for the upload, where each case that gets as far as the
#: survey starts a validation process (0.5 s idle, ~4 s on two loaded cores).
MAX_EXAMPLES = 25
UPLOAD_EXAMPLES = 12
FUZZ_SETTINGS = settings(max_examples=MAX_EXAMPLES, deadline=None, derandomize=True, database=None,
                         suppress_health_check=list(HealthCheck))


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    env = {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_MAX_UPLOAD_BYTES": "2000000",
           "SHSAS_VALIDATE_MEMORY_BYTES": str(512 * 1024**2), "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"}
    proc, base = start_server(tmp, env)
    yield {"base": base, "tmp": tmp, "proc": proc}
    proc.stop()


def _fuzz(base: str, label: str, cases, examples: int) -> str | None:
    """Send ``examples`` generated cases; the first server error's report, or None.

    Raises:
        hypothesis.errors.Unsatisfiable: no case can be generated (negative mode on an
            operation whose parameters are all unconstrained strings: nothing is invalid).
    """
    @given(case=cases)
    @settings(FUZZ_SETTINGS, max_examples=examples)
    def run(case) -> None:
        case.call_and_validate(base_url=base, checks=[not_a_server_error])

    try:
        run()
    except Unsatisfiable:
        raise
    except Exception as exc:  # Schemathesis' report: the check, the response and a curl line
        return f"{label}: {exc}"
    return None


@pytest.mark.parametrize("mode", ["positive", "negative"])
def test_no_server_errors(server, mode: str) -> None:
    """Every operation of the served schema, valid (positive) or invalid (negative) input."""
    # Schemathesis' own pytest integration (schema.parametrize / from_fixture) reads a pytest
    # internal that pytest 9 removed (Function._nodeid), so the operations are driven here.
    api = schemathesis.openapi.from_url(server["base"] + "/openapi.json")
    ops = [result.ok() for result in api.get_all_operations()]
    labels = {op.label for op in ops}
    assert {"POST /reconstructions", "GET /reconstructions", "GET /reconstructions/{job_id}",
            "POST /reconstructions/{job_id}/cancel", "GET /reconstructions/{job_id}/artifacts",
            "GET /reconstructions/{job_id}/artifacts/{name}", "GET /healthz", "GET /readyz",
            "DELETE /reconstructions/{job_id}", "HEAD /reconstructions/{job_id}/artifacts/{name}",
            "HEAD /healthz", "HEAD /readyz"} <= labels
    failures, fuzzed = [], []
    for op in ops:
        cases = op.as_strategy(generation_mode=schemathesis.GenerationMode(mode))
        try:
            examples = UPLOAD_EXAMPLES if op.label == "POST /reconstructions" else MAX_EXAMPLES
            failures.append(_fuzz(server["base"], op.label, cases, examples))
            fuzzed.append(op.label)
        except Unsatisfiable:
            assert mode == "negative", f"{op.label}: no valid input could be generated"
    if mode == "negative":  # the operations with constrained input did get invalid input
        assert {"POST /reconstructions", "GET /reconstructions"} <= set(fuzzed), fuzzed
    failures = [f for f in failures if f]
    assert not failures, "\n\n".join(failures)


@pytest.fixture(scope="module")
def artifact(server) -> dict[str, str]:
    """Path parameters of one artifact of a finished job."""
    survey = write_tiny_survey(Path(server["tmp"]) / "tiny.h5")
    with httpx.Client(base_url=server["base"], timeout=60) as c:
        r = submit(c, survey, {"methods": ["backprojection"], "grid": 16, "device": "cpu"})
        assert r.status_code == 202, r.text
        done = wait_for(c, r.json()["id"], lambda j: j["status"] in ("succeeded", "failed"), 180,
                        "job to finish")
    assert done["status"] == "succeeded", done
    return {"job_id": done["id"], "name": done["artifacts"][0]["name"]}


#: Range header values: well-formed with numbers of any length (often past int()'s 4300-digit
#: limit, which used to give 500), and printable junk.
def _digits(lo: int, hi: int):
    return st.integers(lo, hi).flatmap(lambda n: st.text("0123456789", min_size=n, max_size=n))


RANGES = st.one_of(
    st.from_regex(r"\Abytes=[0-9]{0,12}-[0-9]{0,12}\Z"),
    st.builds(lambda a, b: f"bytes={a}-{b}", _digits(0, 6000), _digits(0, 6000)),
    st.builds(lambda a, b: f"bytes={a}-{b}", _digits(4000, 6000), _digits(0, 20)),
    st.builds(lambda a, b: f"bytes={a}-{b}", _digits(0, 20), _digits(4000, 6000)),
    st.builds(lambda a, b: f"bytes={a}-{b}", st.integers(-10, 10**6), st.integers(-10, 10**6)),
    st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=80),
)


def test_artifact_headers_on_a_real_file(server, artifact) -> None:
    """Generated Range / If-Range / If-None-Match headers against an artifact that exists
    (random job ids only ever reach the 404)."""
    api = schemathesis.openapi.from_url(server["base"] + "/openapi.json")
    op = api["/reconstructions/{job_id}/artifacts/{name}"]["GET"]
    url = f"{server['base']}/reconstructions/{artifact['job_id']}/artifacts/{artifact['name']}"
    etag = httpx.get(url).headers["etag"]
    generated = op.as_strategy(path_parameters=artifact)

    @st.composite
    def cases(draw):
        case = draw(generated)
        headers = dict(case.headers or {})
        headers["Range"] = draw(RANGES)
        if draw(st.booleans()):
            headers["If-Range"] = draw(st.sampled_from([etag, '"stale"', etag + "x"]))
        case.headers = headers
        return case

    failure = _fuzz(server["base"], op.label, cases(), 4 * MAX_EXAMPLES)
    assert failure is None, failure


@pytest.mark.parametrize("path", ["/reconstructions/{job_id}/extract", "/reconstructions/{job_id}/extract/{name}",
                                  "/reconstructions/{job_id}/survey"])
def test_console_routes_on_a_real_job(server, artifact, path: str) -> None:
    """Generated input for the routes made for the console, aimed at a finished job (random job
    ids only ever reach the 404): re-extraction levels and methods, file names."""
    api = schemathesis.openapi.from_url(server["base"] + "/openapi.json")
    op = api[path]["GET"]
    failures = []
    for mode in ("positive", "negative"):
        cases = op.as_strategy(path_parameters={"job_id": artifact["job_id"]},
                               generation_mode=schemathesis.GenerationMode(mode))
        try:
            failures.append(_fuzz(server["base"], f"{op.label} ({mode})", cases, MAX_EXAMPLES))
        except Unsatisfiable:
            assert mode == "negative" and path.endswith("/survey"), f"{op.label}: nothing to generate"
    failures = [f for f in failures if f]
    assert not failures, "\n\n".join(failures)
