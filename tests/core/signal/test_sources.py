"""The one rule for which signals a stage uses (shsas_core.signal.sources.signals_for)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from shsas_core.common.errors import ShsasError
from shsas_core.signal.chain import analytic_samples, matched_filter
from shsas_core.signal.deconv import DeconvConfig, deconvolve
from shsas_core.signal.sources import deconv_config, signals_for
from shsas_core.spec.job import ReconstructionSpec
from tests.conftest import make_survey


def test_auto_prefers_stored_signals_then_deconvolves() -> None:
    survey = make_survey()
    computed = signals_for(survey, "auto")
    assert computed.label == "wiener deconvolution"
    np.testing.assert_array_equal(computed.values, deconvolve(survey))
    stored = (np.ones(survey.shape) * (1 + 2j)).astype(np.complex64)
    survey.extras["deconvolved"] = stored
    got = signals_for(survey, "auto")
    assert got.label == "stored extras/deconvolved" and got.values.dtype == np.complex64
    np.testing.assert_array_equal(got.values, stored)
    # "deconvolve" ignores what is stored: a job's signals depend on its spec and samples only
    np.testing.assert_array_equal(signals_for(survey, "deconvolve").values, computed.values)
    # stored signals of another shape are not the survey's
    survey.extras["deconvolved"] = stored[:, :-1]
    assert signals_for(survey, "auto").label == "wiener deconvolution"
    with pytest.raises(ShsasError, match="no extras/deconvolved"):
        signals_for(survey, "stored")


def test_the_other_sources_are_the_chain_functions() -> None:
    survey = make_survey()
    np.testing.assert_array_equal(signals_for(survey, "matched").values, matched_filter(survey))
    np.testing.assert_array_equal(signals_for(survey, "raw").values, analytic_samples(survey))
    none = signals_for(survey, "deconvolve", DeconvConfig(method="none"))
    assert none.label == "none deconvolution"
    np.testing.assert_array_equal(none.values, analytic_samples(survey))
    with pytest.raises(ShsasError, match="unknown source"):
        signals_for(survey, "nonesuch")  # type: ignore[arg-type]


def test_a_job_deconvolves_as_its_spec_says() -> None:
    cfg = deconv_config(ReconstructionSpec(deconvolution="neural", seed=7))
    assert cfg.method == "neural" and cfg.neural.seed == 7
    assert json.loads(deconv_config(ReconstructionSpec()).model_dump_json())["method"] == "wiener"


@pytest.mark.parametrize("options, label", [
    ([], "stored extras/deconvolved"),
    (["--deconv", "wiener"], "wiener deconvolution"),
    (["--signal", "matched"], "matched filter"),
    (["--deconv", "none"], "raw (analytic)"),
])
def test_shsas_backproject_names_the_signals_it_imaged(tmp_path, capsys, options, label) -> None:
    from shsas_core.cli import main
    from shsas_core.formats.hdf5 import write_survey

    survey = make_survey()
    survey.extras["deconvolved"] = deconvolve(survey)
    path = write_survey(survey, tmp_path / "s.h5")
    rc = main(["backproject", str(path), "--grid", "8", "--device", "cpu", "--backend", "eager", "--quiet",
               "--out", str(tmp_path / "bp"), *options])
    assert rc == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["signal"] == label


def test_raw_signals_are_the_surveys_analytic_samples() -> None:
    # the "raw" source reads the samples as complex through signal.chain.analytic_samples (one
    # definition, with its signal_kind checks) and matches scipy's Hilbert transform
    import scipy.signal

    from shsas_core.signal.sources import signals_for
    from tests.conftest import make_survey

    real = make_survey()
    got = signals_for(real, "raw")
    assert got.label == "raw (analytic)" and np.iscomplexobj(got.values)
    ref = scipy.signal.hilbert(real.samples.astype(np.float64), axis=1)
    assert np.abs(got.values - ref).max() <= 1e-5 * np.abs(ref).max()
    cplx = make_survey(complex_=True)
    assert np.array_equal(signals_for(cplx, "raw").values, cplx.samples)

