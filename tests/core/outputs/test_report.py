import base64
import io
import json
import re

import numpy as np
import trimesh
from PIL import Image

from shsas_core.data.volume import Grid, Volume
from shsas_core.outputs.report import (
    MethodReport,
    Report,
    ReportFigures,
    SignalFit,
    load_report,
    render_html,
    write_report,
)
from shsas_core.spec.job import ReconstructionSpec


def test_report_json_and_html_with_decodable_images(tmp_path):
    g = Grid((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (12, 12, 12))
    r = np.linalg.norm(g.points() - [0, 0, 0.1], axis=1).reshape(g.shape)
    vol = Volume(g, np.exp(-((r / 0.05) ** 2)).astype(np.float32))
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    sphere.apply_translation([0, 0, 0.1])
    rep = Report(
        spec=ReconstructionSpec(methods=["backprojection", "shsas"]),
        survey={"platform": "test", "pings": 8},
        ground_truth=True,
        timings={"deconvolution": 0.5},
        methods=[
            MethodReport(method="backprojection", threshold=0.3, points=10, faces=20, seconds=1.0,
                         metrics={"pc_chamfer_l2": 1e-4, "pc_surface_iou": 0.5, "mesh_surface_f1": None, "mesh_pieces": 7.0},
                         artifacts={"mesh": "backprojection_mesh.ply"}),
            MethodReport(method="shsas", sh_degree=3, threshold=0.4, points=12, faces=30, seconds=2.0,
                         metrics={"pc_chamfer_l2": 5e-5}, loss_curve=[(0, 1.0), (10, 0.3)],
                         signal_errors={"l1_real": 0.1}),
        ],
        artifacts=["report.json"],
    )
    t = np.linspace(0, 1e-3, 50)[None].repeat(2, 0)
    fits = {"shsas": SignalFit(t * 1e3, np.ones((2, 50)) * 1j, np.ones((2, 50)), [0, 3])}
    figs = ReportFigures(volumes={"backprojection": vol, "shsas": vol},
                         meshes={"backprojection": sphere, "shsas": sphere}, gt_mesh=sphere, signal_fits=fits)
    jp, hp = write_report(rep, figs, tmp_path)
    back = load_report(jp)
    assert back == rep
    assert back.metrics()["backprojection"]["pc_surface_iou"] == 0.5
    assert back.metrics()["backprojection"]["mesh_surface_f1"] is None  # undefined: None, as in report.json
    page = open(hp, encoding="utf-8").read()
    imgs = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(imgs) == 4  # MIP, meshes, loss, signals
    for b64 in imgs:
        im = Image.open(io.BytesIO(base64.b64decode(b64)))
        im.load()
        assert im.size[0] > 200 and im.size[1] > 100
    assert "Chamfer-L2" in page and "1.000e-04" in page
    # the primary score heads the table, the paper code's solid F1 and the mesh quality follow
    heads = re.findall(r"<th>([^<]*)</th>", page[page.index("<th>method</th><th>output</th>"):])
    assert heads[2:5] == ["surface F1", "F@5mm", "F@2.5mm"], heads
    assert heads.index("solid F1 (paper code)") < heads.index("pieces") < heads.index("area ratio")
    assert "<td>7</td>" in page  # the mesh's pieces
    # links to artifacts are relative names in the same folder
    assert "href='backprojection_mesh.ply'" in page


def test_warnings_reach_report_json_and_a_box_in_the_html(tmp_path):
    from shsas_core.evaluation.diagnostics import ResultWarning

    warn = ResultWarning(code="box_filling", message="the extracted cloud fills the scene box",
                         measure=0.52, limit=0.4)
    rep = Report(spec=ReconstructionSpec(methods=["backprojection", "reed"]), survey={}, ground_truth=False,
                 methods=[MethodReport(method="backprojection", threshold=0.2, points=5, faces=8, seconds=1.0),
                          MethodReport(method="reed", sh_degree=0, threshold=0.2, points=9, faces=8, seconds=1.0,
                                       warnings=[warn])])
    jp, hp = write_report(rep, ReportFigures(), tmp_path)
    back = load_report(jp)
    assert back.warnings() == {"backprojection": [], "reed": [warn]}
    page = open(hp, encoding="utf-8").read()
    box = re.search(r"<div class='warn'>(.*?)</div>", page, re.S)
    assert box and "reed" in box.group(1) and "box_filling" in box.group(1) and "0.52" in box.group(1)
    assert page.index("class='warn'") < page.index("<h2>Survey</h2>")  # shown first
    # a report without warnings shows no box, and done.json files from before the field still load
    clean = back.model_copy(update={"methods": back.methods[:1]})
    assert "class='warn'" not in render_html(clean, ReportFigures())
    old = back.methods[0].model_dump(exclude={"warnings"})
    assert MethodReport.model_validate(old).warnings == []


def test_mesh_check_warnings_reach_report_json_and_the_html(tmp_path):
    """A mesh failing the mesh checks (from its metrics, as the pipeline does) gets a plain box:
    with ground truth all three checks, without it the pieces alone."""
    from shsas_core.evaluation.diagnostics import mesh_warnings
    from shsas_core.evaluation.metrics import MESH_CHECKS

    foam = {"mesh_pieces": 485.0, "mesh_area_ratio": 2.2, "mesh_normal_consistency": 0.6, "pc_surface_f1": 0.4}
    found = mesh_warnings(foam)
    assert [w.code for w in found] == ["mesh_pieces", "mesh_area_ratio", "mesh_normal_consistency"]
    assert [w.limit for w in found] == [MESH_CHECKS.max_pieces, MESH_CHECKS.area_ratio[1],
                                        MESH_CHECKS.min_normal_consistency]
    assert [w.code for w in mesh_warnings({"mesh_pieces": 4.0})] == ["mesh_pieces"]  # no ground truth
    assert mesh_warnings({"mesh_pieces": 3.0, "mesh_area_ratio": 0.71, "mesh_normal_consistency": None}) == []
    assert [w.code for w in mesh_warnings({"mesh_area_ratio": 0.5})] == ["mesh_area_ratio"]
    rep = Report(spec=ReconstructionSpec(methods=["backprojection"]), survey={}, ground_truth=True,
                 methods=[MethodReport(method="backprojection", threshold=0.2, points=5, faces=8, seconds=1.0,
                                       metrics=foam, warnings=found)])
    jp, hp = write_report(rep, ReportFigures(), tmp_path)
    assert [w["code"] for w in json.loads(open(jp).read())["methods"][0]["warnings"]] == [w.code for w in found]
    page = open(hp, encoding="utf-8").read()
    box = re.search(r"<div class='warn'>(.*?)</div>", page, re.S).group(1)
    assert "not one clean surface" in box and "485 pieces" in box and "2.20x the true area" in box
