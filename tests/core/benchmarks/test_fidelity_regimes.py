"""The fidelity benchmark's survey regimes (benchmarks/bench_fidelity.py) and the azimuth-arc
ping subset they use (shsas_core.simulation.trajectory.azimuth_arc_indices). No simulation of the dense
surveys: the regimes are checked on their trajectories, the arc on a small simulated sphere."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from shsas_core.simulation.simulate import simulate_shape
from shsas_core.simulation.trajectory import (
    TrajectoryConfig,
    azimuth_arc_indices,
    azimuth_deg,
    full_trajectory,
    make_trajectory,
)
from tests.helpers.bench_scripts import load_bench


@pytest.fixture(scope="module")
def bench():
    return load_bench("bench_fidelity")


def test_arc_keeps_exactly_the_half_turn_of_a_circular_trajectory() -> None:
    cfg = TrajectoryConfig(heights=3, angles=120)
    tx, _ = full_trajectory(cfg)
    keep = azimuth_arc_indices(tx, 0.0, 180.0)
    # ping k sits at azimuth 3°·(k mod 120): [0°, 180°) is angle index 0..59, 180° itself is out
    expected = np.flatnonzero(np.arange(len(tx)) % 120 < 60)
    np.testing.assert_array_equal(keep, expected)
    assert keep.dtype == np.int64


def test_arc_wraps_through_zero_and_a_full_circle_keeps_all() -> None:
    tx, _ = full_trajectory(TrajectoryConfig(heights=1, angles=8))  # every 45°
    np.testing.assert_array_equal(azimuth_arc_indices(tx, 270.0, 450.0), [0, 1, 6, 7])
    np.testing.assert_array_equal(azimuth_arc_indices(tx, 90.0, 180.0), [2, 3])
    np.testing.assert_array_equal(azimuth_arc_indices(tx, 10.0, 370.0), np.arange(8))
    np.testing.assert_allclose(azimuth_deg(tx), np.arange(8) * 45.0, atol=1e-9)


@pytest.mark.parametrize("arc", [(0.0, 0.0), (90.0, 45.0), (0.0, 361.0)])
def test_arc_rejects_empty_or_overfull_arcs(arc: tuple[float, float]) -> None:
    with pytest.raises(ValueError, match="arc"):
        azimuth_arc_indices(np.zeros((2, 3)), *arc)


def test_sparse_regime_is_a_reproducible_tenth_of_dense(bench) -> None:
    dense_tx, _, _ = make_trajectory(bench.REGIMES["dense"].simulation_config(0).trajectory)
    _, _, idx0 = make_trajectory(bench.REGIMES["sparse"].simulation_config(0).trajectory)
    _, _, again = make_trajectory(bench.REGIMES["sparse"].simulation_config(0).trajectory)
    _, _, idx1 = make_trajectory(bench.REGIMES["sparse"].simulation_config(1).trajectory)
    assert len(dense_tx) == 3600
    assert abs(len(idx0) / len(dense_tx) - 0.10) <= 0.01
    np.testing.assert_array_equal(idx0, again)
    assert not np.array_equal(idx0, idx1)
    assert np.all(np.diff(idx0) > 0) and idx0.max() < len(dense_tx)


def test_regimes_simulate_what_they_say(bench) -> None:
    cfg = {name: r.simulation_config(3) for name, r in bench.REGIMES.items()}
    dense = cfg["dense"]
    assert (dense.trajectory.heights, dense.trajectory.angles, dense.snr_db, dense.seed) == (30, 120, 20.0, 3)
    assert dense.scattering.specular_weight == 0
    assert cfg["noisy"].snr_db == 5.0
    assert cfg["anisotropic"].scattering.specular_weight > 0
    # the limited aperture selects from the dense survey, so it shares its simulation (and cache)
    assert cfg["limited"] == dense


def test_limited_regime_selects_the_arc_of_a_survey(bench) -> None:
    survey = simulate_shape("sphere", heights=2, angles=8, snr_db=None, seed=0)
    kept = bench.REGIMES["limited"].select(survey)
    assert kept.num_pings == 8  # 4 of the 8 azimuths (0°, 45°, 90°, 135°) at both heights
    np.testing.assert_array_equal(kept.extras["ping_index"], [0, 1, 2, 3, 8, 9, 10, 11])
    assert np.all(azimuth_deg(kept.tx) < 180.0)
    assert bench.REGIMES["dense"].select(survey) is survey


def test_hard_scenes_are_built_in_shapes_and_the_specular_one_scatters_only_through_its_lobe(bench) -> None:
    from shsas_core.simulation.shapes import SHAPES

    for scene in bench.HARD_SCENES:
        assert bench.scene_source(scene, Path("/nonexistent")) in SHAPES, scene
    spec = bench.REGIMES["dense"].simulation_config(0, "specular").scattering
    assert (spec.lambert, spec.specular_weight) == ("none", 1.0) and spec.specular_exponent > 20
    # the regime's own settings hold for every other scene, and the regime's seed for all
    assert bench.REGIMES["dense"].simulation_config(0, "bowl") == bench.REGIMES["dense"].simulation_config(0)
    assert bench.REGIMES["noisy"].simulation_config(2, "specular").snr_db == 5.0


def test_mesh_check_flags_a_foam_and_spares_multi_piece_scenes(bench) -> None:
    def cell(scene: str, pieces: float, ratio: float) -> object:
        return bench.Cell("dense", scene, 0, "backprojection", {"mesh_pieces": pieces, "mesh_area_ratio": ratio,
                                                                "mesh_normal_consistency": 0.9, "seconds": 1.0}, "")

    bad = bench.mesh_check("backprojection", [cell("bunny", 485.0, 2.2), cell("sphere", 1.0, 1.0)])
    assert bad.status == "FAIL" and "bunny/seed0: pieces, area_ratio" in bad.detail and "sphere" not in bad.detail
    ok = bench.mesh_check("backprojection", [cell("pipe", 2.0, 1.0), cell("sphere", 1.0, 1.1)])
    assert ok.status == "PASS" and "1 run(s)" in ok.detail


def test_result_records_are_one_per_regime_and_seed_with_scene_rows_means_and_checks(bench, tmp_path) -> None:
    spec = bench.ReconstructionSpec()
    profile = tmp_path / "defaults"
    machine = {"cpu": "test cpu", "nproc": 2, "gpu": None, "torch": "x", "load_avg_before": [0.1, 0.1, 0.1]}
    f1 = {("bunny", "backprojection"): 0.60, ("bunny", "shsas"): 0.70,
          ("cube", "backprojection"): 0.50, ("cube", "shsas"): 0.64}
    for scene in ("bunny", "cube"):
        methods = {m: {"spec": spec.model_dump(mode="json"), "seconds": 10.0, "machine": machine, "code": "abc",
                       "finished": "2026-11-27T14:00:00", "metrics": {"pc_surface_f1": f1[(scene, m)],
                                                                      "mesh_chamfer_l2": 1e-4}}
                   for m in ("backprojection", "shsas")}
        cell = profile / "anisotropic" / scene / "seed0"
        cell.mkdir(parents=True)
        bench.write_json({"regime": "anisotropic", "scene": scene, "seed": 0, "methods": methods},
                         cell / "result.json")
    out = tmp_path / "records"
    out.mkdir()
    (path,) = bench.write_result_records(profile, "defaults", spec, folder=out)
    rec = json.loads(path.read_text())
    assert rec["name"] == "fidelity-defaults-anisotropic-seed0" and "bunny, cube (2 scene(s))" in rec["title"]
    rows = {r["row"]: r for r in rec["rows"]}
    assert rows["cube / SH-SAS"]["pc_surface_f1"] == 0.64
    assert rows["mean of 2 / SH-SAS"]["pc_surface_f1"] == pytest.approx(0.67)
    assert rows["mean of 2 / Backprojection"]["pc_surface_f1"] == pytest.approx(0.55)
    # SH-SAS is 0.12 over backprojection: the hard regime's + 0.10 passes; there is no Reed to compare
    assert "PASS SH-SAS surface F1 >= backprojection + 0.10" in rec["notes"]
    assert "n/a SH-SAS surface F1 >= Reed + 0.03" in rec["notes"]


def test_reextract_reuses_only_finished_runs_of_the_same_spec_and_survey(bench) -> None:
    spec = bench.base_spec("defaults", {}).model_copy(update={"methods": ["shsas"], "seed": 0, "device": "cpu"})
    entry = {"spec": spec.model_dump(mode="json"), "code": "old", "survey_key": "k"}
    assert bench.reusable(entry, "k", spec)
    assert not bench.reusable(entry, "other survey", spec)
    assert not bench.reusable(entry, "k", spec.model_copy(update={"iters": spec.iters + 1}))
    assert not bench.reusable({**entry, "error": "boom"}, "k", spec)
    assert not bench.reusable({}, "k", spec)
    with pytest.raises(SystemExit):
        bench.parse_args(["--fresh", "--reextract"])


def _one_cell_profile(bench, root: Path, cpu: str, methods: tuple[str, ...]) -> Path:
    """A profile folder holding one finished (noisy, bunny, seed 1) cell measured on ``cpu``."""
    spec = bench.ReconstructionSpec()
    machine = {"cpu": cpu, "nproc": 2, "gpu": None, "torch": "x", "load_avg_before": [0.1, 0.1, 0.1]}
    profile = root / cpu / "defaults"
    cell = profile / "noisy" / "bunny" / "seed1"
    cell.mkdir(parents=True)
    entries = {m: {"spec": spec.model_dump(mode="json"), "seconds": 1.0, "machine": machine, "code": "abc",
                   "finished": "2026-11-28T14:00:00", "metrics": {"pc_surface_f1": 0.6}} for m in methods}
    bench.write_json({"regime": "noisy", "scene": "bunny", "seed": 1, "methods": entries}, cell / "result.json")
    return profile


def test_a_record_from_another_cpu_model_is_kept_beside_not_replaced(bench, tmp_path) -> None:
    spec = bench.ReconstructionSpec()
    out = tmp_path / "records"
    out.mkdir()
    (xeon,) = bench.write_result_records(_one_cell_profile(bench, tmp_path, "Intel(R) Xeon(R) Processor",
                                                           ("backprojection", "shsas")), "defaults", spec, folder=out)
    (epyc,) = bench.write_result_records(_one_cell_profile(bench, tmp_path, "AMD EPYC", ("backprojection", "shsas")),
                                         "defaults", spec, folder=out)
    assert xeon.name == "fidelity-defaults-noisy-seed1.json"
    assert epyc.name == "fidelity-defaults-noisy-seed1-amd-epyc.json"
    assert json.loads(xeon.read_text())["machine"]["cpu"] == "Intel(R) Xeon(R) Processor"
    assert json.loads(epyc.read_text())["title"].endswith(", AMD EPYC")
    # a rerun on the stored record's own CPU model replaces it
    (again,) = bench.write_result_records(_one_cell_profile(bench, tmp_path / "again", "Intel(R) Xeon(R) Processor",
                                                            ("backprojection", "shsas")), "defaults", spec, folder=out)
    assert again == xeon and sorted(p.name for p in out.iterdir()) == [epyc.name, xeon.name]


def test_a_record_command_names_the_methods_it_ran(bench, tmp_path) -> None:
    spec = bench.ReconstructionSpec()
    out = tmp_path / "records"
    out.mkdir()
    (two,) = bench.write_result_records(_one_cell_profile(bench, tmp_path, "cpu a", ("backprojection", "shsas")),
                                        "defaults", spec, folder=out)
    assert "--methods backprojection,shsas --seeds 1" in json.loads(two.read_text())["command"]
    (three,) = bench.write_result_records(_one_cell_profile(bench, tmp_path / "b", "cpu a", bench.METHODS),
                                          "defaults", spec, folder=out)
    assert "--methods" not in json.loads(three.read_text())["command"]


def test_a_run_records_only_the_regimes_and_seeds_it_measured(bench, tmp_path) -> None:
    # the --out folder also holds a cell of another (regime, seed), left by an earlier run that was
    # stopped: a run's --record must not turn it into a record; --merge records what the folder holds
    spec = bench.ReconstructionSpec()
    profile = _one_cell_profile(bench, tmp_path, "cpu a", ("backprojection", "shsas"))
    dense = profile / "dense" / "bunny" / "seed0"
    dense.mkdir(parents=True)
    noisy = json.loads((profile / "noisy" / "bunny" / "seed1" / "result.json").read_text())
    bench.write_json({**noisy, "regime": "dense", "seed": 0}, dense / "result.json")
    out = tmp_path / "records"
    out.mkdir()
    (run,) = bench.write_result_records(profile, "defaults", spec, folder=out, only={("dense", 0)})
    assert run.name == "fidelity-defaults-dense-seed0.json" and [p.name for p in out.iterdir()] == [run.name]
    merged = bench.write_result_records(profile, "defaults", spec, folder=out)
    assert sorted(p.name for p in merged) == ["fidelity-defaults-dense-seed0.json", "fidelity-defaults-noisy-seed1.json"]
