"""docs/formats.md's meta table is enough to write the meta attribute: nested objects or dotted
keys, and every validation error names its fix (issue 13, item 6).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from shsas_core.errors import ShsasError, SurveyValidationError
from shsas_core.importers import load_survey
from shsas_core.survey import parse_meta

# -- every error names a fix -----------------------------------------------------------------------

META_ERRORS = [
    ({"pulse.f_begin": 1e4}, "meta.pulse.f_begin", "Extra inputs"),
    ({"pulse": {"f_begin": 1e4}}, "meta.pulse.f_begin", "Extra inputs"),
    ({"sample_rate": 1e5}, "meta.sample_rate", "Extra inputs"),
    ({"fs": -1}, "meta.fs", "greater than 0"),
    ({"fs": "fast"}, "meta.fs", "valid number"),
    ({"signal_kind": "iq"}, "meta.signal_kind", "'real', 'analytic' or 'baseband'"),
    ({"platform": "x" * 65}, "meta.platform", "at most 64"),
    ({"scene_box.min": [0, 0]}, "meta.scene_box.min", "three numbers"),
    ({"scene_box.min": [0, 0, 0, 0]}, "meta.scene_box.min", "at most 3 items"),
    ({"scene_box.min": [1, 1, 1], "scene_box.max": [0, 0, 0]}, "meta.scene_box", "must exceed min"),
    ({"fs": 40e3}, "meta", "not above twice"),
    ({"signal_kind": "baseband"}, "meta", "carrier_hz is required"),
    ({"pulse.f_start": 1e4, "pulse": {"f_start": 2e4}}, "meta.pulse.f_start", "given twice"),
    ({"pulse": 3, "pulse.f_start": 1e4}, "meta.pulse", "both as a value"),
    ("[1, 2]", "meta", "JSON object"),
    ("{fs: 1}", "meta", "not valid JSON"),
]


@pytest.mark.parametrize(("meta", "field", "problem"), META_ERRORS, ids=[e[1] + ":" + e[2] for e in META_ERRORS])
def test_meta_errors_name_the_field_and_a_fix(meta, field: str, problem: str) -> None:
    with pytest.raises(SurveyValidationError) as ei:
        parse_meta(meta if isinstance(meta, str) else json.dumps(meta))
    msg = str(ei.value)
    assert msg.startswith(f"{field}: ") and problem in msg, msg
    assert re.search(r"\(fix: [^)]+", msg), msg


def test_every_malformed_file_error_carries_a_fix(tmp_path: Path) -> None:
    from tests.core.test_malformed import CASES

    missing = []
    for build, _field, _problem in CASES:
        folder = tmp_path / build.__name__
        folder.mkdir()
        with pytest.raises(ShsasError) as ei:
            load_survey(build(folder))
        if "(fix: " not in str(ei.value):
            missing.append(f"{build.__name__}: {ei.value}")
    assert not missing, "\n".join(missing)


def test_meta_fields_nested_dotted_or_mixed_are_the_same() -> None:
    nested = {"fs": 1e5, "pulse": {"f_start": 1e4, "f_stop": 3e4, "window": "hann"},
              "scene_box": {"min": [-1, -1, 0], "max": [1, 1, 1]}, "attrs": {"writer": "x"}}
    dotted = {"fs": 1e5, "pulse.f_start": 1e4, "pulse.f_stop": 3e4, "pulse.window": "hann",
              "scene_box.min": [-1, -1, 0], "scene_box.max": [1, 1, 1], "attrs.writer": "x"}
    mixed = {"fs": 1e5, "pulse": {"f_start": 1e4}, "pulse.f_stop": 3e4, "pulse.window": "hann",
             "scene_box": {"min": [-1, -1, 0], "max": [1, 1, 1]}, "attrs.writer": "x"}
    want = parse_meta(json.dumps(nested))
    assert want.pulse.window == "hann" and want.attrs == {"writer": "x"}
    assert parse_meta(json.dumps(dotted)) == want == parse_meta(mixed)
