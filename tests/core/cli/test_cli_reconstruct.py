"""`shsas reconstruct`, `shsas evaluate` and `shsas demo` through the real CLI entry point."""

import json

import numpy as np
import pytest
import trimesh

from shsas_core.cli import main
from shsas_core.formats.hdf5 import write_survey
from shsas_core.simulation.simulate import simulate_shape


@pytest.fixture(scope="module")
def survey_file(tmp_path_factory):
    s = simulate_shape("cube", heights=2, angles=36, snr_db=20.0, seed=1)
    return write_survey(s, tmp_path_factory.mktemp("survey") / "cube.h5"), s


def test_reconstruct_then_evaluate(survey_file, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # rich wraps tables to the terminal width
    path, survey = survey_file
    out = tmp_path / "out"
    rc = main(["reconstruct", str(path), "--methods", "backprojection", "--grid", "20", "--device", "cpu",
               "--out", str(out), "--quiet"])
    assert rc == 0
    cap = capsys.readouterr()
    text = cap.out
    assert "backprojection" in text and "report.html" in text and "Chamfer" in text
    rep = json.loads((out / "report.json").read_text())
    codes = [w["code"] for w in rep["methods"][0]["warnings"]]
    # a good backprojection passes the volume's checks; its mesh is judged by its measured
    # quality, one stderr line per failed bound
    from shsas_core.evaluation.diagnostics import mesh_warnings

    assert codes == [w.code for w in mesh_warnings(rep["methods"][0]["metrics"])], codes
    assert cap.err.count("warning: backprojection: the mesh") == len(codes) == cap.err.count("warning:")
    assert rep["spec"]["grid"] == 20 and rep["spec"]["methods"] == ["backprojection"]
    # evaluate the folder against the survey: same numbers as the pipeline computed
    rc = main(["evaluate", str(out), "--gt", str(path), "--json"])
    assert rc == 0
    ev = json.loads(capsys.readouterr().out)
    for k, v in rep["methods"][0]["metrics"].items():
        assert ev["backprojection"][k] == pytest.approx(v, rel=1e-9, abs=1e-12), k
    # the table form prints the new columns and the same mesh warnings as the run
    assert main(["evaluate", str(out), "--gt", str(path)]) == 0
    cap = capsys.readouterr()
    assert "surface F1" in cap.out and "solid F1" in cap.out and "pieces" in cap.out
    assert [ln for ln in cap.err.splitlines() if ln.startswith("warning:")] == [
        f"warning: {w.line('backprojection')}" for w in mesh_warnings(rep["methods"][0]["metrics"])]
    # a single mesh file against a GT mesh file with an explicit box
    gt_path = tmp_path / "gt.ply"
    trimesh.Trimesh(survey.gt_vertices, survey.gt_faces).export(gt_path)
    box = ",".join(str(x) for x in (*survey.meta.scene_box.min, *survey.meta.scene_box.max))
    rc = main(["evaluate", str(out / "backprojection_mesh.ply"), "--gt", str(gt_path), f"--box={box}", "--json"])
    assert rc == 0
    one = json.loads(capsys.readouterr().out)["backprojection_mesh"]
    assert one["mesh_chamfer_l2"] == pytest.approx(rep["methods"][0]["metrics"]["mesh_chamfer_l2"], rel=1e-5)  # GT via float32 PLY
    # a point-cloud PLY is scored as points
    rc = main(["evaluate", str(out / "backprojection_pointcloud.ply"), "--gt", str(gt_path), f"--box={box}", "--json"])
    assert rc == 0
    pc = json.loads(capsys.readouterr().out)["backprojection_pointcloud"]
    assert np.isclose(pc["pc_surface_iou"], rep["methods"][0]["metrics"]["pc_surface_iou"])


def test_a_failed_result_prints_a_warning_and_reaches_the_report(survey_file, tmp_path, capsys, monkeypatch):
    """A survey of silence (a recording with the transmitter off) backprojects to a volume of
    zeros: the run completes, but says the result collapsed."""
    import dataclasses

    monkeypatch.setenv("COLUMNS", "200")
    _, survey = survey_file
    silent = write_survey(dataclasses.replace(survey, samples=np.zeros_like(survey.samples)), tmp_path / "silent.h5")
    out = tmp_path / "out"
    rc = main(["reconstruct", str(silent), "--methods", "backprojection", "--grid", "12", "--device", "cpu",
               "--out", str(out), "--quiet"])
    assert rc == 0  # the job ran; its result is flagged, not failed
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.startswith("warning: ")]
    assert lines == ["warning: backprojection: the volume is near-constant (relative spread (max-min)/max "
                     "of |values|): nothing was reconstructed (0 vs limit 0.01)"], cap.err
    assert "warning:" not in cap.out
    rep = json.loads((out / "report.json").read_text())
    assert [(w["code"], w["measure"], w["limit"]) for w in rep["methods"][0]["warnings"]] == [("collapsed", 0.0, 0.01)]
    assert "class='warn'" in (out / "report.html").read_text()
    # a resumed run (nothing recomputed) says it again
    assert main(["reconstruct", str(silent), "--methods", "backprojection", "--grid", "12", "--device", "cpu",
                 "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr().err.count("warning: backprojection:") == 1


@pytest.mark.parametrize("argv, needle", [
    (["reconstruct", "missing.h5", "--out", "o"], "missing.h5"),
    (["reconstruct", "x.h5", "--out", "o", "--methods", "backprojection,nope"], "--methods"),
    (["reconstruct", "x.h5", "--out", "o", "--threshold", "1.5"], "--threshold"),
    (["reconstruct", "x.h5", "--out", "o", "--occupancy", "most"], "--occupancy"),
    (["reconstruct", "x.h5", "--out", "o", "--occupancy", "1.5"], "occupancy"),
    (["evaluate", "nowhere", "--gt", "sphere"], "nowhere"),
    (["evaluate", ".", "--gt", "sphere", "--box", "1,2"], "--box"),
])
def test_bad_input_exits_2_with_one_line(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and "Traceback" not in err


@pytest.mark.slow
def test_demo_tiny(tmp_path, capsys, monkeypatch):
    # the demo's wiring, end to end; the neural methods start empty (--init none) because the
    # warm start costs the same 300 steps of 32k points at any grid (it dominated this test), and
    # is checked in neural/test_warmstart.py and in the pipeline's identity test
    monkeypatch.setenv("COLUMNS", "200")
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--shape", "cube", "--heights", "1", "--angles", "24",
               "--iters", "2", "--grid", "10", "--bins", "4", "--rays", "8", "--device", "cpu", "--quiet",
               "--init", "none"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "report.html" in text and "shsas" in text and "Chamfer" in text
    rep = json.loads((out / "report.json").read_text())
    assert [m["method"] for m in rep["methods"]] == ["backprojection", "reed", "shsas"]
    assert (out / "survey.h5").is_file()


def test_demo_and_reconstruct_run_the_one_default_spec():
    """`shsas demo` and `shsas reconstruct` with no options run ReconstructionSpec() itself."""
    from shsas_core.cli import build_parser
    from shsas_core.cli.reconstruct import spec_from_args
    from shsas_core.spec.job import ReconstructionSpec

    parser = build_parser()
    for argv in (["demo"], ["reconstruct", "x.h5", "--out", "o"]):
        assert spec_from_args(parser.parse_args(argv)) == ReconstructionSpec()
    assert spec_from_args(parser.parse_args(["demo", "--iters", "7"])).iters == 7  # options win


def test_paper_preset_is_one_flag_away():
    from shsas_core.cli import build_parser
    from shsas_core.cli.reconstruct import spec_from_args
    from shsas_core.spec.job import PAPER_SETTINGS, ReconstructionSpec

    parser = build_parser()
    spec = spec_from_args(parser.parse_args(["reconstruct", "x.h5", "--out", "o", "--preset", "paper"]))
    assert spec == ReconstructionSpec(**PAPER_SETTINGS)
    spec = spec_from_args(parser.parse_args(["reconstruct", "x.h5", "--out", "o", "--preset", "paper",
                                             "--iters", "9"]))
    assert spec.iters == 9 and spec.init == "none"


def test_occupancy_and_sparsity_options():
    from shsas_core.cli import build_parser
    from shsas_core.cli.reconstruct import spec_from_args

    parser = build_parser()
    base = ["reconstruct", "x.h5", "--out", "o"]
    spec = spec_from_args(parser.parse_args([*base, "--occupancy", "none", "--sparsity", "0"]))
    assert spec.occupancy is None and spec.sparsity == 0.0
    spec = spec_from_args(parser.parse_args([*base, "--occupancy", "0.1", "--sparsity", "2.5"]))
    assert spec.occupancy == 0.1 and spec.sparsity == 2.5


def test_help_reports_the_spec_defaults():
    """The CLI's help text takes each default from the spec, so the two cannot disagree."""
    from shsas_core.cli import build_parser
    from shsas_core.spec.job import ReconstructionSpec

    text = " ".join(_help(build_parser(), "reconstruct").split())
    text = text.split("reconstruction spec (defaults", 1)[1]  # the options' section, not the usage
    d = ReconstructionSpec()
    for opt, value in (("--iters", d.iters), ("--lr", d.lr), ("--bins", d.num_bins), ("--rays", d.num_rays),
                       ("--init", d.init), ("--target", d.target), ("--occupancy", d.occupancy),
                       ("--sparsity", d.sparsity)):
        assert f"(default {value})" in text.split(opt, 1)[1].split(" --", 1)[0], opt


def _help(parser, command: str) -> str:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):
        parser.parse_args([command, "--help"])
    return buf.getvalue()



@pytest.mark.slow
def test_reconstruct_the_real_deconvolved_bunny_zip_with_every_method(tmp_path, capsys):
    """The real AirSAS bunny's deconvolved pings (first 46 turntable steps of all 150 levels,
    zipped: the whole scan's range window) through `shsas reconstruct`, every method, short
    (10 iterations from the empty field: the warm start alone takes minutes on 6,900 pings)."""
    from tests.helpers.airsas_zips import WINDOW_ROWS, deconvolved_zip

    upload = deconvolved_zip(tmp_path / "bunny_rows.zip", rows=WINDOW_ROWS)
    out = tmp_path / "out"
    rc = main(["reconstruct", str(upload), "--methods", "backprojection,reed,shsas", "--grid", "24",
               "--iters", "10", "--init", "none", "--device", "cpu", "--out", str(out), "--quiet"])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert [m["method"] for m in rep["methods"]] == ["backprojection", "reed", "shsas"]
    assert rep["survey"]["pings"] == 150 * WINDOW_ROWS
    for m in ("backprojection", "reed", "shsas"):
        vol = np.load(out / f"{m}_volume.npy")
        assert vol.shape == (24, 24, 19) and np.isfinite(vol).all() and np.abs(vol).max() > 0
        assert trimesh.load(out / f"{m}_mesh.ply", force="mesh").faces.shape[0] > 0
    assert "report.html" in capsys.readouterr().out


def test_reconstruct_without_out_writes_beside_the_survey_name_and_resumes(survey_file, tmp_path, capsys,
                                                                           monkeypatch):
    """`shsas reconstruct FILE` with no options runs: the outputs go to FILE's name plus
    '_reconstruction' in the current folder, and the same bare command again resumes there."""
    path, _ = survey_file
    monkeypatch.chdir(tmp_path)
    args = ["reconstruct", str(path), "--methods", "backprojection", "--grid", "12", "--device", "cpu", "--quiet"]
    assert main(args) == 0
    out = tmp_path / "cube_reconstruction"
    assert json.loads((out / "report.json").read_text())["spec"]["methods"] == ["backprojection"]
    assert str(out.name) in capsys.readouterr().out
    stamp = (out / "backprojection_volume.npy").stat().st_mtime_ns
    assert main(args) == 0  # finished methods are skipped, not redone
    assert (out / "backprojection_volume.npy").stat().st_mtime_ns == stamp


def test_default_out_dir_names(tmp_path):
    from pathlib import Path

    from shsas_core.cli.reconstruct import default_out_dir

    (tmp_path / "scan.v2").mkdir()
    assert default_out_dir(tmp_path / "data" / "scan.h5") == Path("scan_reconstruction")
    assert default_out_dir("scan.zip") == Path("scan_reconstruction")
    assert default_out_dir(tmp_path / "scan.v2").name == "scan.v2_reconstruction"  # a folder keeps its whole name
