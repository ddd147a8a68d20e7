"""Resume bookkeeping (shsas_core.pipeline.job_cache): what a re-run job finds, and what it must not."""

from __future__ import annotations

import json

import numpy as np

from shsas_core.outputs.report import MethodReport, SignalFit
from shsas_core.pipeline.job_cache import JobCache, survey_fingerprint
from shsas_core.spec.job import ReconstructionSpec
from tests.conftest import make_survey


def test_another_spec_or_survey_clears_and_a_threshold_change_keeps(tmp_path):
    survey, spec = make_survey(), ReconstructionSpec()
    folder = tmp_path / "checkpoints"
    JobCache(folder, spec, survey).save_array("deconvolved", np.ones(survey.shape, np.complex64))
    kept = JobCache(folder, spec.model_copy(update={"threshold": 0.3}), survey)
    assert kept.array("deconvolved", survey.shape) is not None
    assert kept.array("deconvolved", (1, 2)) is None  # another shape is not this job's
    JobCache(folder, spec.model_copy(update={"iters": 7}), survey)
    assert not (folder / "deconvolved.npy").exists()
    JobCache(folder, spec, survey).save_array("deconvolved", np.ones(survey.shape, np.complex64))
    JobCache(folder, spec, make_survey(seed=1))
    assert not (folder / "deconvolved.npy").exists()
    assert survey_fingerprint(survey) != survey_fingerprint(make_survey(seed=1))


def test_a_key_written_before_a_spec_field_existed_keeps_the_checkpoints_at_its_default(tmp_path):
    survey, spec = make_survey(), ReconstructionSpec()
    folder = tmp_path / "checkpoints"
    JobCache(folder, spec, survey).save_array("deconvolved", np.ones(survey.shape, np.complex64))
    key = json.loads((folder / "run_key.json").read_text())
    del key["spec"]["tv_phase"]  # as written before the spec had the field
    (folder / "run_key.json").write_text(json.dumps(key))
    assert JobCache(folder, spec, survey).array("deconvolved", survey.shape) is not None
    JobCache(folder, spec.model_copy(update={"tv_phase": 0.5}), survey)  # not the run the key names
    assert not (folder / "deconvolved.npy").exists()


def test_method_cache_round_trip(tmp_path):
    m = JobCache(tmp_path / "c", ReconstructionSpec(), make_survey()).method("shsas")
    assert m.finished() is None and m.load_fit() is None
    fit = SignalFit(np.arange(4.0), np.ones((1, 4), np.complex64), np.zeros((1, 4), np.complex64), [3])
    m.save_fit(fit)
    back = m.load_fit()
    assert back.pings == [3] and np.array_equal(back.measured, fit.measured)
    rep = MethodReport(method="shsas", sh_degree=3, threshold=0.2, points=5, faces=2, seconds=1.0,
                       metrics={}, signal_errors={}, loss_curve=[], artifacts={}, origin_offset=[0, 0, 0],
                       warnings=[])
    m.mark_done(rep, {"threshold": None, "version": 3})
    assert m.finished() == rep
    assert m.extracted_with({"threshold": None, "version": 3})
    assert not m.extracted_with({"threshold": 0.5, "version": 3})
