"""Child process that opens and validates one uploaded survey (run by :mod:`service.validation`).

Runs under address-space, CPU-time and file-size limits set by the parent, with ``TMPDIR``
inside the upload's own folder, so a hostile or enormous file can only exhaust this process
and whatever it leaves is removed with the upload. It reads the upload once and writes, into
the output folder it is given:

* ``survey.h5``: the survey converted to the canonical format, when the upload is in another
  format (an AirSAS zip, a pickle, a zipped deconvolved-ping or SVSS folder): the worker then
  reads a canonical file, block by block, and nothing reads the upload again;
* ``survey/``: the survey view the API serves (:mod:`service.survey_view`).

With ``view_only`` it writes the survey view alone, for a job stored before views were made
at upload (its input was validated then).

Prints one JSON line on stdout: ``{"ok": true, "format": ..., "summary": {...}, "converted":
bool}`` or ``{"ok": false, "status": 4xx, "error": ...}``.
"""

from __future__ import annotations

import json
import sys

#: Rows of samples checked for NaN/inf per read, so the scan's memory stays bounded.
SCAN_ELEMENTS = 8 * 1024 * 1024
#: The canonical file a non-canonical upload is converted to, inside the output folder.
CONVERTED_NAME = "survey.h5"


def _scan_samples_finite(path: str) -> None:
    import h5py
    import numpy as np

    from shsas_core.common.errors import SurveyValidationError

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


def _check_memory(survey, cfg: dict) -> None:
    """Refuse a job the workers could not hold, from the declared sizes alone."""
    if cfg.get("budget") is None or cfg.get("spec") is None:
        return
    from shsas_core.spec.job import ReconstructionSpec
    from shsas_core.spec.memory import check_job_memory

    check_job_memory(survey, ReconstructionSpec.model_validate_json(cfg["spec"]), int(cfg["budget"]))


def _check_parts(path: str, cfg: dict) -> list[str]:
    """Refuse a ground-truth mesh or /extras over the upload caps, from their declared shapes
    (before either is read); return the names of the extras."""
    from shsas_core.common.errors import ShsasError
    from shsas_core.formats.hdf5 import declared_parts

    class TooLarge(ShsasError):
        http_status = 413

    try:
        parts = declared_parts(path)
    except OSError:
        return []  # not readable as HDF5: read_survey names the problem precisely
    mesh, cap = parts["ground_truth_elements"], int(cfg["max_ground_truth_elements"])
    if mesh > cap:
        raise TooLarge(f"ground_truth: the mesh has {mesh} vertices and faces, over the upload limit of {cap} "
                       "(SHSAS_MAX_GROUND_TRUTH_ELEMENTS) (fix: decimate the mesh, or leave /ground_truth out)")
    extras, cap = sum(parts["extras"].values()), int(cfg["max_extras_bytes"])
    if extras > cap:
        raise TooLarge(f"extras: the arrays under /extras declare {extras} bytes, over the upload limit of "
                       f"{cap} (SHSAS_MAX_EXTRAS_BYTES) (fix: leave /extras out: no stage of a job reads them)")
    return sorted(parts["extras"])


def _named(survey, display_name: str | None):
    """``survey`` with ``attrs.file`` (the importers record the file they read) naming the
    client's file rather than the server's ``upload.part``."""
    if not display_name or "file" not in survey.meta.attrs:
        return survey
    survey.meta = survey.meta.model_copy(update={"attrs": {**survey.meta.attrs, "file": display_name}})
    return survey


def validate(path: str, cfg: dict) -> dict:
    from pathlib import Path

    import numpy as np

    from jobs.layout import SURVEY_VIEW
    from shsas_core.common.errors import ShsasError, SurveyValidationError
    from shsas_core.formats import detect_format, load_survey
    from shsas_core.formats.hdf5 import read_survey, summarize, write_survey

    from .survey_view import ping_indices, write_view

    out = Path(cfg["out_dir"])
    fmt = detect_format(path)
    if fmt == "shsas":
        extras = _check_parts(path, cfg)
        # Header and geometry first (cheap, checks every shape), then the samples in blocks.
        survey = read_survey(path, load_samples=False, load_extras=False)
        if not cfg.get("view_only"):
            _check_memory(survey, cfg)
            _scan_samples_finite(path)
        summary = {**summarize(survey), "extras": extras}
        import h5py

        with h5py.File(path, "r") as f:
            rows = f["pings/samples"][ping_indices(survey.num_pings)]
    else:
        _check_memory(load_survey(path, fmt, load_samples=False), cfg)
        survey = _named(load_survey(path, fmt), cfg.get("display_name"))
        if survey.samples is not None and not np.all(np.isfinite(survey.samples)):
            raise SurveyValidationError("pings/samples", "contains NaN or inf")
        summary = summarize(survey)
        rows = survey.samples[ping_indices(survey.num_pings)]
    if cfg.get("view_only"):  # the survey view of a job stored before views were made at upload
        write_view(survey, summary, rows, out / SURVEY_VIEW)
        return {"format": fmt, "summary": summary, "converted": False}
    if summary["warnings"]:
        # A job on such a file would run for hours and make noise: refuse it now (docs/service.md).
        raise ShsasError(summary["warnings"][0])
    if fmt != "shsas":
        write_survey(survey, out / CONVERTED_NAME)
    write_view(survey, summary, rows, out / SURVEY_VIEW)
    return {"format": fmt, "summary": summary, "converted": fmt != "shsas"}


def main() -> int:
    cfg = json.loads(sys.argv[1])
    path, memory_bytes, cpu_s = cfg["path"], int(cfg["memory_bytes"]), int(cfg["cpu_s"])
    import resource
    import signal

    # Limits first, before numpy/h5py allocate anything. No file this process writes may be
    # larger than the memory it may hold: a write past that fails (EFBIG) instead of filling
    # the disk, and the signal that would kill the process is ignored so the error is named.
    resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s + 5))
    resource.setrlimit(resource.RLIMIT_FSIZE, (memory_bytes, memory_bytes))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        # The readers first, apart: failing here is the limit being too small for the
        # validator itself, not the file's fault.
        import h5py  # noqa: F401
        import numpy  # noqa: F401

        import shsas_core.formats
        import shsas_core.formats.hdf5  # noqa: F401
    except (ImportError, MemoryError, OSError) as exc:
        sys.stdout.write(json.dumps({"ok": False, "status": 413, "error": (
            "survey: the validator cannot start within SHSAS_VALIDATE_MEMORY_BYTES="
            f"{memory_bytes}; raise it ({type(exc).__name__})")}) + "\n")
        return 0
    try:
        from shsas_core.common.errors import ShsasError

        try:
            out = {"ok": True, **validate(path, cfg)}
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
