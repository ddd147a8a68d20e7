"""The pulse of a baseband survey: a complex /pulse/samples is already basebanded (docs/formats.md,
as the SVSS importer stores it), so the matched filter must not baseband it a second time."""

from __future__ import annotations

import numpy as np
import pytest

from shsas_core.data.pulse import lfm_pulse
from shsas_core.data.survey import Survey, SurveyMeta
from shsas_core.formats.svss import CARRIER_HZ, FS_HZ, baseband_pulse
from shsas_core.formats.svss import PULSE as SVSS_PULSE
from shsas_core.signal.chain import analytic_signal, baseband, matched_filter


def test_matched_filter_of_baseband_survey_with_basebanded_pulse() -> None:
    """The SVSS importer stores the basebanded pulse; processing must not baseband it again."""
    p = lfm_pulse(SVSS_PULSE.f_start, SVSS_PULSE.f_stop, SVSS_PULSE.duration, FS_HZ, SVSS_PULSE.window,
                  SVSS_PULSE.window_param)
    x = np.zeros((2, 400))
    x[:, 100:100 + p.size] = p
    t0 = np.zeros(2)
    bb = baseband(analytic_signal(x), t0, FS_HZ, CARRIER_HZ).astype(np.complex64)
    meta = SurveyMeta(fs=FS_HZ, sound_speed=1450, pulse=SVSS_PULSE, signal_kind="baseband", carrier_hz=CARRIER_HZ,
                      scene_box={"min": [-1, -1, -1], "max": [1, 1, 1]})
    tx = np.array([[0, 0, 0.5]] * 2)
    peaks = {}
    for name, pulse in (("basebanded", baseband_pulse()), ("real passband", p)):
        mf = np.abs(matched_filter(Survey(tx=tx, rx=tx, samples=bb, t0=t0, meta=meta, pulse=pulse))[0])
        peaks[name] = (int(mf.argmax()), mf.max() / np.sum(p**2))
    assert peaks["basebanded"][0] == peaks["real passband"][0] == 100, peaks
    assert peaks["basebanded"][1] == pytest.approx(peaks["real passband"][1], rel=0.05), peaks


def test_replica_of_a_basebanded_pulse_is_the_basebanded_replica() -> None:
    """Deconvolution's replica: the stored basebanded pulse as it is, the real one basebanded."""
    from shsas_core.signal.deconv import replica_in_frame

    meta = SurveyMeta(fs=FS_HZ, sound_speed=1450, pulse=SVSS_PULSE, signal_kind="baseband", carrier_hz=CARRIER_HZ,
                      scene_box={"min": [-1, -1, -1], "max": [1, 1, 1]})
    tx = np.array([[0, 0, 0.5]])
    p = lfm_pulse(SVSS_PULSE.f_start, SVSS_PULSE.f_stop, SVSS_PULSE.duration, FS_HZ, SVSS_PULSE.window,
                  SVSS_PULSE.window_param)
    samples = np.ones((1, 64), np.complex64)
    stored = replica_in_frame(Survey(tx=tx, rx=tx, samples=samples, t0=np.zeros(1), meta=meta, pulse=baseband_pulse()))
    made = replica_in_frame(Survey(tx=tx, rx=tx, samples=samples, t0=np.zeros(1), meta=meta, pulse=p))
    np.testing.assert_allclose(stored, made, atol=1e-9 * np.abs(made).max())
