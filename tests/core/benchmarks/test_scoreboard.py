"""docs/results.md's scoreboard is what benchmarks/results/*.json give, and goes stale when they change."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.helpers.bench_scripts import load_bench

records = load_bench("records")
scoreboard = load_bench("scoreboard")


def test_the_committed_scoreboard_matches_the_committed_records() -> None:
    old, new = scoreboard.generate()
    assert old == new, "docs/results.md is stale: run python benchmarks/scoreboard.py"
    assert scoreboard.main(["--check"]) == 0


def test_every_record_follows_the_schema_and_says_when_it_is_transcribed() -> None:
    found, _ = records.read_records()
    assert found, "benchmarks/results/ holds no records"
    for r in found:
        assert records.validate(r) == []
        if r["transcribed"] is not None:
            assert r["transcribed"]["from"]
        text = scoreboard.section(r)
        assert f"`{r['command']}`" in "\n".join(text)


def _copy(tmp_path: Path) -> tuple[Path, Path]:
    doc = tmp_path / "results.md"
    shutil.copy(scoreboard.DOC, doc)
    folder = tmp_path / "results"
    shutil.copytree(records.RESULTS_DIR, folder)
    return doc, folder


def test_a_changed_figure_fails_the_check_until_regenerated(tmp_path: Path) -> None:
    doc, folder = _copy(tmp_path)
    args = ["--doc", str(doc), "--results", str(folder)]
    assert scoreboard.main(["--check", *args]) == 0
    path = sorted(folder.glob("*.json"))[0]
    record = json.loads(path.read_text())
    key = next(k for k, _, fmt in record["columns"] if fmt and isinstance(record["rows"][0].get(k), float))
    record["rows"][0][key] = record["rows"][0][key] + 0.5
    path.write_text(json.dumps(record))
    assert scoreboard.main(["--check", *args]) == 1
    assert scoreboard.main(args) == 0
    assert scoreboard.main(["--check", *args]) == 0
    assert doc.read_text() != scoreboard.DOC.read_text()


def test_a_new_or_removed_record_fails_the_check(tmp_path: Path) -> None:
    doc, folder = _copy(tmp_path)
    args = ["--check", "--doc", str(doc), "--results", str(folder)]
    first = sorted(folder.glob("*.json"))[0]
    record = json.loads(first.read_text())
    record["name"] = "zz-added"
    (folder / "zz-added.json").write_text(json.dumps(record))
    assert scoreboard.main(args) == 1
    (folder / "zz-added.json").unlink()
    first.unlink()
    assert scoreboard.main(args) == 1


def test_a_malformed_record_is_named(tmp_path: Path) -> None:
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "bad.json").write_text(json.dumps({"schema": 1, "name": "bad"}))
    with pytest.raises(ValueError, match="bad.json: missing 'benchmark'"):
        records.read_records(folder)
    good = json.loads(sorted(records.RESULTS_DIR.glob("*.json"))[0].read_text())
    (folder / "bad.json").write_text(json.dumps({**good, "load": {"loadavg": None, "note": ""}}))
    with pytest.raises(ValueError, match="needs a note"):
        records.read_records(folder)


def test_files_of_another_format_are_listed_not_tabulated(tmp_path: Path) -> None:
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "gpu-h100.json").write_text(json.dumps({"card": "H100"}))
    found, others = records.read_records(folder)
    assert found == [] and others == ["gpu-h100.json"]
    assert "gpu-h100.json" in scoreboard.render(found, others)


def test_the_page_needs_both_markers() -> None:
    with pytest.raises(ValueError, match="once each"):
        scoreboard.splice("no markers here", "x")
    assert scoreboard.splice(f"a\n{scoreboard.BEGIN}\nold\n{scoreboard.END}\nb", "new\n") == \
        f"a\n{scoreboard.BEGIN}\nnew\n{scoreboard.END}\nb"


def test_make_record_fills_in_provenance() -> None:
    r = records.make_record("extract", "extract-x", "t", "python benchmarks/bench_extract.py",
                            [("extraction", "extraction", ""), ("points", "points", "{:.0f}")],
                            [{"extraction": "default", "points": 3.0}],
                            machine_info=records.machine(), load_info=records.load())
    assert r["transcribed"] is None and len(r["load"]["loadavg"]) == 3
    assert r["machine"]["cores"] >= 1 and r["machine"]["cpu"]
    assert "| default | 3 |" in "\n".join(scoreboard.section(r))
