"""The pipeline's first stage: the survey, checked against the job's memory budget before its
samples are read."""

from __future__ import annotations

import os

from shsas_core.common.errors import ShsasError
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, never_stop, no_progress
from shsas_core.data.survey import Survey
from shsas_core.spec.job import ReconstructionSpec


def load_input(survey: Survey | str | os.PathLike, spec: ReconstructionSpec | None = None,
               memory_budget: int | None = None, should_stop: StopFn = never_stop,
               progress: ProgressFn = no_progress) -> Survey:
    """The survey with its samples, after checking the job fits ``memory_budget`` bytes.

    The "load" stage is reported only once the header is read and checked, so a bad file ends
    with its one-line error and no progress output.

    The check uses the sizes a file declares, before its samples are read; canonical files are
    then read block by block, polling ``should_stop``. Their ``/extras`` are not read: no stage
    of the pipeline uses them.
    """
    from shsas_core.spec.memory import check_job_memory

    if isinstance(survey, Survey):
        if survey.samples is None:
            raise ShsasError("survey: samples were not loaded (read it with load_samples=True)")
        if memory_budget is not None and spec is not None:
            check_job_memory(survey, spec, memory_budget)
        return survey
    from shsas_core.formats import detect_format, load_survey
    from shsas_core.formats.hdf5 import read_survey

    fmt = detect_format(survey)
    if fmt == "shsas":
        header = read_survey(survey, load_samples=False, load_extras=False)
    else:
        header = load_survey(survey, fmt, load_samples=False)
    if memory_budget is not None and spec is not None:
        check_job_memory(header, spec, memory_budget)
    progress(0.0, "load", {})  # the stage starts here, so a cancel during it is reported as such
    check_stop(should_stop)
    if fmt == "shsas":
        return read_survey(survey, load_extras=False, should_stop=should_stop)
    return load_survey(survey, fmt)
