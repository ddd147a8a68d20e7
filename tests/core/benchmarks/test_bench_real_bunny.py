"""bench_real_bunny's goal checks: the real-data goals as PASS/FAIL lines, and a reason when
Reed is not between backprojection and SH-SAS."""

from __future__ import annotations

from tests.helpers.bench_scripts import load_bench

bench = load_bench("bench_real_bunny")


def row(method: str, chamfer: float, acc: float, fscore: float, p: float, r: float, **extra) -> dict:
    return {"method": method, "chamfer_l2": chamfer, "chamfer_l2_accuracy": acc,
            "chamfer_l2_completeness": chamfer - acc, "fscore": fscore, "fscore_precision": p,
            "fscore_recall": r, **extra}


def test_goals_met_and_reed_between() -> None:
    rows = [row("backprojection", 3.0e-4, 2.0e-4, 0.36, 0.23, 0.83, mesh_pieces=4),
            row("reed", 2.7e-4, 1.5e-4, 0.39, 0.30, 0.50, seconds=200.0),
            row("shsas", 2.3e-4, 1.2e-4, 0.42, 0.33, 0.52, seconds=210.0, mesh_pieces=1)]
    lines = bench.goal_checks(rows)
    assert all(x.startswith("PASS") for x in lines), lines
    assert sum("Reed between" in x for x in lines) == 2


def test_chamfer_goal_fails_at_090_and_reed_best_says_why() -> None:
    rows = [row("backprojection", 2.72e-4, 2.0e-4, 0.367, 0.23, 0.83),
            row("reed", 2.55e-4, 1.1e-4, 0.417, 0.33, 0.50),
            row("shsas", 2.45e-4, 1.3e-4, 0.427, 0.33, 0.49)]
    rows[2]["chamfer_l2"] = 0.9 * 2.72e-4  # 0.9 x: above the 0.8 goal, below Reed
    lines = bench.goal_checks(rows)
    assert lines[0].startswith("FAIL SH-SAS Chamfer-L2 0.90 x")
    assert lines[1].startswith("PASS SH-SAS F@5mm +0.060")
    chamfer_line = next(x for x in lines if "Reed" in x and "Chamfer" in x)
    assert chamfer_line.startswith("PASS")  # 2.448e-4 <= 2.55e-4 <= 2.72e-4
    rows[2]["chamfer_l2"] = 2.82e-4  # SH-SAS now worse than both
    chamfer_line = next(x for x in bench.goal_checks(rows) if "Reed" in x and "Chamfer" in x)
    assert chamfer_line.startswith("FAIL Reed not between on Chamfer-L2: it has the best")
    # the reason names the halves: Reed's cloud has fewer stray points than SH-SAS's
    assert "fewer stray points" in chamfer_line and "1.10e-04 against 1.30e-04" in chamfer_line


def test_missing_methods_give_only_the_checks_they_can() -> None:
    lines = bench.goal_checks([row("backprojection", 3e-4, 2e-4, 0.36, 0.2, 0.8)])
    assert lines == []
    slow = bench.goal_checks([row("reed", 3e-4, 2e-4, 0.4, 0.3, 0.5, seconds=bench.MAX_NEURAL_SECONDS + 1)])
    assert slow == [f"FAIL Reed {bench.MAX_NEURAL_SECONDS + 1} s (goal <= {bench.MAX_NEURAL_SECONDS} s)"]


def test_mesh_goals_are_judged_when_the_meshes_were_scored() -> None:
    rows = [row("backprojection", 3.0e-4, 2.0e-4, 0.36, 0.23, 0.83, mesh_chamfer_l2=4.0e-4, mesh_fscore=0.30),
            row("shsas", 2.9e-4, 1.2e-4, 0.40, 0.33, 0.52, mesh_chamfer_l2=3.0e-4, mesh_fscore=0.40)]
    lines = bench.goal_checks(rows)
    assert "PASS SH-SAS Chamfer-L2 (meshes) 0.75 x backprojection's (goal <= 0.8)" in lines
    assert "PASS SH-SAS F@5mm (meshes) +0.100 over backprojection (goal >= +0.05)" in lines
    assert lines[0].startswith("FAIL SH-SAS Chamfer-L2 0.97 x")
