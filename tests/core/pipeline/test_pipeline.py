"""End-to-end pipeline on a tiny physically meaningful survey (point scatterers on a sphere)."""

import json

import numpy as np
import pytest
import trimesh

from shsas_core.common.errors import Cancelled
from shsas_core.evaluation.diagnostics import mesh_warnings
from shsas_core.outputs.artifacts import artifact_names
from shsas_core.outputs.export import read_point_cloud_ply, read_volume_npy
from shsas_core.outputs.report import load_report
from shsas_core.pipeline.job import PipelineResult, holdout_split, run
from shsas_core.simulation.simulate import simulate_shape
from shsas_core.spec.job import ReconstructionSpec


@pytest.fixture(scope="module")
def sphere_survey():
    """The built-in sphere (radius 8 cm on z = 0), 3 rings of 40 pings, 20 dB."""
    return simulate_shape("sphere", heights=3, angles=40, snr_db=20.0, seed=0)


def test_holdout_split():
    tr, ho = holdout_split(10, 0.2, seed=1)
    assert len(ho) == 2 and len(tr) == 8 and set(tr) | set(ho) == set(range(10))
    np.testing.assert_array_equal(holdout_split(10, 0.2, seed=1)[1], ho)
    assert len(holdout_split(10, 0.0, 0)[1]) == 0


def test_backprojection_pipeline_end_to_end_and_resume(tmp_path, sphere_survey):
    survey = sphere_survey
    # the paper's extraction (every voxel >= τ, marching cubes): this coarse image of 120 pings
    # is a thick shell straddling the sphere, which the checks below measure; the default
    # (ridge + Poisson) is switched to at the end
    spec = ReconstructionSpec(methods=["backprojection"], grid=24, device="cpu", surface="threshold",
                              mesher="marching_cubes")
    stages = []
    res = run(spec, survey, tmp_path, progress=lambda f, s, m: stages.append((f, s)))
    assert isinstance(res, PipelineResult)
    names = artifact_names("backprojection")
    for n in names.values():
        assert n in res.artifacts and (tmp_path / n).is_file()
    assert {"report.json", "report.html"} <= set(res.artifacts)
    # everything loads back
    vol = read_volume_npy(tmp_path / names["volume"])
    assert vol.values.dtype == np.complex64 and vol.grid.shape == (24, 24, 24)
    pc = read_point_cloud_ply(tmp_path / names["pointcloud"])
    mesh = trimesh.load(tmp_path / names["mesh_ply"], process=False)
    glb = trimesh.load(tmp_path / names["mesh_glb"])
    assert len(pc["x"]) > 0 and len(mesh.faces) > 0 and len(glb.geometry) == 1
    rep = load_report(res.report_json)
    assert rep.methods[0].method == "backprojection"
    assert res.device == rep.device == "cpu" and "on cpu" in (tmp_path / "report.html").read_text()
    # a good image passes the volume's checks; its mesh is judged by its measured quality
    assert res.warnings == {"backprojection": mesh_warnings(res.metrics["backprojection"])}
    assert rep.methods[0].warnings == res.warnings["backprojection"]
    assert all(w.code.startswith("mesh_") for w in rep.methods[0].warnings)
    # the image lands on the 8 cm sphere: centred on it, Chamfer-L1 of a few voxels
    m = res.metrics["backprojection"]
    pts = np.stack([pc["x"], pc["y"], pc["z"]], 1)
    # (sensors look down from 0.11-0.86 m, so the lit upper half pulls the centroid up)
    np.testing.assert_allclose(pts.mean(0)[:2], [0, 0], atol=0.01)
    assert 0.04 < pts.mean(0)[2] < 0.16
    assert m["pc_chamfer_l1"] < 0.025, m
    assert pc["scalar_magnitude"].min() >= rep.methods[0].threshold
    assert 0 < m["pc_surface_precision"] <= 1 and 0 < m["mesh_surface_f1"] <= 1 and m["mesh_pieces"] >= 1
    assert json.loads((tmp_path / "report.json").read_text())["ground_truth"] is True
    fr = [f for f, _ in stages]
    assert fr == sorted(fr) and fr[-1] == 1.0
    # re-run: the finished method is skipped and gives the same metrics
    stages.clear()
    res2 = run(spec, survey, tmp_path, progress=lambda f, s, m: stages.append((f, s, dict(m))))
    assert res2.metrics == res.metrics and res2.warnings == res.warnings
    assert res.metrics["backprojection"]["points"] == rep.methods[0].points == len(pc["x"])
    assert any(m.get("cached") for _, s, m in stages if s == "backprojection")
    # a new threshold re-extracts from the saved volume without reconstructing again
    stages.clear()
    res3 = run(spec.model_copy(update={"threshold": 0.5}), survey, tmp_path,
               progress=lambda f, s, m: stages.append((f, s, dict(m))))
    assert load_report(res3.report_json).methods[0].threshold == 0.5
    assert any(m.get("cached") for _, s, m in stages if s == "backprojection")
    assert res3.metrics["backprojection"]["points"] < res.metrics["backprojection"]["points"]
    assert read_point_cloud_ply(tmp_path / names["pointcloud"])["scalar_magnitude"].min() >= 0.5
    # the default extraction also re-extracts without reconstructing: one sheet of points (fewer
    # than the thick cloud at the same τ), each above τ, and a Poisson mesh
    stages.clear()
    res4 = run(spec.model_copy(update={"surface": "ridge", "mesher": "poisson"}), survey, tmp_path,
               progress=lambda f, s, m: stages.append((f, s, dict(m))))
    assert any(m.get("cached") for _, s, m in stages if s == "backprojection")
    assert 0 < res4.metrics["backprojection"]["points"] < res.metrics["backprojection"]["points"]
    assert res4.metrics["backprojection"]["faces"] > 0
    ridge_pc = read_point_cloud_ply(tmp_path / names["pointcloud"])
    assert ridge_pc["scalar_magnitude"].min() >= rep.methods[0].threshold
    # a different reconstruction spec clears the checkpoints and recomputes
    stages.clear()
    run(spec.model_copy(update={"grid": 20}), survey, tmp_path,
        progress=lambda f, s, m: stages.append((f, s, dict(m))))
    assert not any(m.get("cached") for _, _, m in stages)
    assert read_volume_npy(tmp_path / names["volume"]).grid.shape == (20, 20, 20)


def test_without_ground_truth_the_mesh_pieces_are_still_measured_and_checked(tmp_path, sphere_survey):
    import dataclasses

    from shsas_core.evaluation.metrics import mesh_pieces

    survey = dataclasses.replace(sphere_survey, gt_vertices=None, gt_faces=None)
    res = run(ReconstructionSpec(methods=["backprojection"], grid=20, device="cpu"), survey, tmp_path)
    mesh = trimesh.load(tmp_path / artifact_names("backprojection")["mesh_ply"], process=False)
    rep = load_report(res.report_json)
    assert not rep.ground_truth
    assert rep.methods[0].metrics == {"mesh_pieces": float(mesh_pieces(mesh.vertices, mesh.faces))}
    assert res.warnings["backprojection"] == mesh_warnings(rep.methods[0].metrics)


def test_cancel_between_steps(tmp_path, sphere_survey):
    survey = sphere_survey
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 2

    with pytest.raises(Cancelled):
        run(ReconstructionSpec(methods=["backprojection"], grid=16, device="cpu"), survey, tmp_path,
            should_stop=stop)
    assert not (tmp_path / "report.json").exists()


@pytest.mark.slow
def test_neural_methods_end_to_end_with_holdout_and_resume(tmp_path, sphere_survey):
    # no warm start: its fixed 300 distillation steps were most of this test's time, and the stop
    # below then fell inside the second method's warm start instead of its training (the warm
    # start is checked in test_warmstart, and in the pipeline's default chain by test_pipeline_identity)
    spec = ReconstructionSpec(methods=["reed", "shsas"], sh_degree=1, iters=4, grid=12, num_bins=8,
                              num_rays=16, holdout_fraction=0.1, device="cpu", seed=3, init="none")
    stops = {"n": 0, "armed": True}

    def stop_in_shsas_fit():
        # cancel once, during the second method's training
        if stops["armed"] and (tmp_path / "checkpoints" / "reed" / "done.json").exists():
            stops["n"] += 1
            if stops["n"] > 3:
                stops["armed"] = False
                return True
        return False

    with pytest.raises(Cancelled):
        run(spec, sphere_survey, tmp_path, should_stop=stop_in_shsas_fit)
    assert (tmp_path / "checkpoints" / "reed" / "done.json").exists()
    assert not (tmp_path / "checkpoints" / "shsas" / "done.json").exists()
    seen = []
    res = run(spec, sphere_survey, tmp_path, progress=lambda f, s, m: seen.append((s, dict(m))))
    assert any(s == "reed" and m.get("cached") for s, m in seen)  # finished method skipped
    rep = load_report(res.report_json)
    by = {m.method: m for m in rep.methods}
    assert by["reed"].sh_degree == 0 and by["shsas"].sh_degree == 1
    for m in by.values():
        assert len(m.loss_curve) == 4 and [i for i, _ in m.loss_curve] == [0, 1, 2, 3]
        assert set(m.signal_errors) >= {"l1_real", "mse_abs"}  # held-out pings were scored
        assert all(np.isfinite(v) for v in m.signal_errors.values())
        vol = read_volume_npy(tmp_path / m.artifacts["volume"])
        assert vol.values.dtype == np.float32 and vol.grid.shape == (12, 12, 12)
    assert set(res.metrics) == {"reed", "shsas"} and "pc_chamfer_l2" in res.metrics["shsas"]


def test_spec_maps_onto_trainer_and_encoding():
    from shsas_core.methods.neural import train_config
    from shsas_core.neural.fields import PAPER_GPU_ENCODING
    from shsas_core.neural.fields import encoding_preset as encoding_config

    spec = ReconstructionSpec(iters=250, lr=0.02, num_bins=7, num_rays=9, pings_per_batch=3, seed=5)
    cfg = train_config(spec)
    assert (cfg.iters, cfg.lr, cfg.num_bins, cfg.num_rays, cfg.pings_per_batch, cfg.seed) == (250, 0.02, 7, 9, 3, 5)
    assert cfg.checkpoint_every == 25 and cfg.lr_final is None
    assert train_config(ReconstructionSpec(lr=0.02, lr_final=1e-4)).lr_final == 1e-4
    assert encoding_config("paper_gpu") == PAPER_GPU_ENCODING
    small = encoding_config("small")
    assert (small.n_levels, small.log2_table_size, small.finest_resolution) == (8, 13, 128)


def test_spec_target_reaches_the_trainer():
    from shsas_core.methods.neural import train_config

    assert ReconstructionSpec().target == "coherent"
    assert train_config(ReconstructionSpec()).target == "coherent"
    assert train_config(ReconstructionSpec(target="envelope")).target == "envelope"


@pytest.mark.slow  # 100 iterations of a tiny fit: ~10 s on 2 cores, longer when they are shared
def test_a_fit_that_learns_nothing_reports_it(tmp_path, sphere_survey):
    """A learning rate of 1e-7 leaves the field at its initial value: the volume is flat and the
    data loss does not fall, and report.json, done.json and the result all say so."""
    from shsas_core.evaluation.diagnostics import LOSS_MIN_ITERS

    # from the near-empty field of the paper: a warm start (spec.init = "backprojection", where the
    # spec has it) would hand the field the image's contrast, and only the loss check would fire
    cold = {"init": "none"} if "init" in ReconstructionSpec.model_fields else {}
    spec = ReconstructionSpec(methods=["reed"], iters=LOSS_MIN_ITERS, lr=1e-7, grid=12, num_bins=8, num_rays=8,
                              encoding="small", target="envelope", device="cpu", **cold)
    res = run(spec, sphere_survey, tmp_path)
    codes = [w.code for w in res.warnings["reed"]]
    assert codes == ["collapsed", "loss_not_falling"], res.warnings
    assert [w["code"] for w in json.loads((tmp_path / "report.json").read_text())["methods"][0]["warnings"]] == codes
    # re-extracting at another τ keeps the fit's verdict and checks the volume again
    res2 = run(spec.model_copy(update={"threshold": 0.5}), sphere_survey, tmp_path)
    assert [w.code for w in res2.warnings["reed"]] == codes
