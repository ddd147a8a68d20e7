"""Child process that opens and validates one uploaded survey (run by :mod:`service.validation`).

Runs under an address-space and CPU-time limit set by the parent, so a hostile or enormous
HDF5 file can only exhaust this process. Prints one JSON line on stdout:
``{"ok": true, "format": ..., "summary": {...}}`` or ``{"ok": false, "status": 4xx, "error": ...}``.
"""

from __future__ import annotations

import json
import sys

#: Rows of samples checked for NaN/inf per read, so the scan's memory stays bounded.
SCAN_ELEMENTS = 8 * 1024 * 1024


def _scan_samples_finite(path: str) -> None:
    import h5py
    import numpy as np

    from shsas_core.errors import SurveyValidationError

    with h5py.File(path, "r") as f:
        ds = f["pings/samples"]
        n, t = ds.shape
        rows = max(1, SCAN_ELEMENTS // max(t, 1))
        for start in range(0, n, rows):
            block = ds[start:start + rows]
            if not np.all(np.isfinite(block)):
                bad = start + int(np.argwhere(~np.isfinite(block))[0, 0])
                raise SurveyValidationError("pings/samples", f"contains NaN or inf (first at ping {bad})",
                                            "drop or repair the bad pings before upload")


def _check_memory(survey, job: tuple[int, str] | None) -> None:
    """Refuse a job the workers could not hold, from the declared sizes alone."""
    if job is None:
        return
    from shsas_core.memory import check_job_memory
    from shsas_core.spec import ReconstructionSpec

    budget, spec_json = job
    check_job_memory(survey, ReconstructionSpec.model_validate_json(spec_json), budget)


def validate(path: str, job: tuple[int, str] | None = None) -> dict:
    import numpy as np

    from shsas_core.importers import detect_format, load_survey
    from shsas_core.io import summarize

    fmt = detect_format(path)
    if fmt == "shsas":
        # Header and geometry first (cheap, checks every shape), then the samples in blocks.
        survey = load_survey(path, fmt, load_samples=False)
        _check_memory(survey, job)
        _scan_samples_finite(path)
    else:
        _check_memory(load_survey(path, fmt, load_samples=False), job)
        survey = load_survey(path, fmt)
        if survey.samples is not None and not np.all(np.isfinite(survey.samples)):
            from shsas_core.errors import SurveyValidationError

            raise SurveyValidationError("pings/samples", "contains NaN or inf")
    summary = summarize(survey)
    if summary["warnings"]:
        # A job on such a file would run for hours and make noise: refuse it now (docs/service.md).
        from shsas_core.errors import ShsasError

        raise ShsasError(summary["warnings"][0])
    return {"format": fmt, "summary": summary}


def main() -> int:
    path, memory_bytes, cpu_s = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    # Optional: the worker memory budget and the job's spec (JSON), to refuse jobs too large to run.
    job = (int(sys.argv[4]), sys.argv[5]) if len(sys.argv) > 5 else None
    import resource

    # Limits first, before numpy/h5py allocate anything.
    resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s + 5))
    try:
        # The readers first, apart: failing here is the limit being too small for the
        # validator itself, not the file's fault.
        import h5py  # noqa: F401
        import numpy  # noqa: F401

        import shsas_core.importers
        import shsas_core.io  # noqa: F401
    except (ImportError, MemoryError, OSError) as exc:
        sys.stdout.write(json.dumps({"ok": False, "status": 413, "error": (
            "survey: the validator cannot start within SHSAS_VALIDATE_MEMORY_BYTES="
            f"{memory_bytes}; raise it ({type(exc).__name__})")}) + "\n")
        return 0
    try:
        from shsas_core.errors import ShsasError

        try:
            out = {"ok": True, **validate(path, job)}
        except ShsasError as exc:
            out = {"ok": False, "status": getattr(exc, "http_status", 422), "error": str(exc)}
        except ImportError as exc:
            out = {"ok": False, "status": 422,
                   "error": f"file: this format needs a reader that is not installed in this build ({exc})"}
    except MemoryError:
        out = {"ok": False, "status": 413,
               "error": "survey: validating it needs more memory than SHSAS_VALIDATE_MEMORY_BYTES allows"}
    except Exception as exc:  # any other failure to read is still the file's fault, not a 500
        out = {"ok": False, "status": 422,
               "error": f"file: could not be read as a survey ({type(exc).__name__}: {str(exc)[:300]})"}
    sys.stdout.write(json.dumps(out, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
