"""bench_demo's record rows come from a report.json: each method's metrics and its wall time."""

from __future__ import annotations

from tests.helpers.bench_scripts import load_bench

bench_demo = load_bench("bench_demo")


def test_rows_carry_each_methods_metrics_and_seconds() -> None:
    report = {"methods": [
        {"method": "backprojection", "seconds": 31.9, "metrics": {"mesh_surface_f1": 0.71, "mesh_pieces": 1}},
        {"method": "shsas", "seconds": 340.3, "metrics": {"pc_surface_f1": 0.64}},
    ]}
    rows = bench_demo.rows_from_report(report)
    assert [r["seconds"] for r in rows] == [31.9, 340.3]
    assert rows[0]["mesh_surface_f1"] == 0.71 and rows[0]["pc_surface_f1"] is None
    assert rows[1]["pc_surface_f1"] == 0.64
    assert {r["method"] for r in rows} == {bench_demo.LABELS["backprojection"], bench_demo.LABELS["shsas"]}
