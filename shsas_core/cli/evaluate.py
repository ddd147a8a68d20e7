"""`shsas evaluate OUT_DIR_or_FILE --gt MESH_or_SURVEY`: score existing reconstructions."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from shsas_core.common.errors import ShsasError

#: Margin around the GT mesh bounds for the occupancy box when no scene box is known, m.
GT_BOX_MARGIN = 0.02


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate", help="score reconstructions against a ground-truth mesh (surface F1, F-score, Chamfer, mesh quality)",
        description="Score existing outputs with the project's metrics (shsas_core/evaluation/metrics.py): surface "
        "IoU/precision/recall/F1 on 5 mm voxels over the scene box (voxels within 5 mm of the surface; "
        "the primary score), F-score at 5 mm and 2.5 mm and Chamfer-L2 (m²) / Chamfer-L1 (m) against "
        "20,000 area-weighted GT surface samples, the paper code's solid F1, and for meshes pieces, area "
        "ratio and normal consistency. TARGET is a `shsas reconstruct` output "
        "folder (every {method}_pointcloud.ply and {method}_mesh.ply in it is scored) or one PLY/OBJ/"
        "STL/GLB file (a file without faces is scored as a point cloud).",
        epilog="The scene box comes from --gt when it is a survey, else from TARGET/report.json, "
        f"else from the GT mesh bounds plus {GT_BOX_MARGIN * 100:g} cm. "
        "Example: shsas evaluate out/ --gt survey.h5")
    p.add_argument("target", help="output folder of `shsas reconstruct`, or a mesh / point-cloud file")
    p.add_argument("--gt", required=True, metavar="MESH_or_SURVEY",
                   help="ground truth: a mesh file (metres, survey frame), a built-in shape name, or a survey file with a ground-truth mesh")
    p.add_argument("--box", default=None, metavar="XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX",
                   help="scene box for the occupancy voxels, m (overrides the rule above); write --box=-0.1,... when it starts with a minus")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--write", action="store_true", help="also write TARGET/evaluation.json (folders only)")
    p.set_defaults(func=run)


def _load_gt(path: str):
    """(vertices, faces, scene box or None) from a mesh or a survey file."""
    from shsas_core.simulation.shapes import SHAPES, load_mesh

    p = Path(path)
    if not p.exists():
        if path.lower() in SHAPES:  # a built-in shape, as `shsas demo --shape` simulates it
            m = load_mesh(path)
            return m.vertices, m.faces, None
        raise ShsasError(f"--gt: '{p}' does not exist")
    if p.suffix.lower() in (".h5", ".hdf5") or p.is_dir():
        from shsas_core.formats import load_survey

        s = load_survey(p, load_samples=False)
        if not s.has_ground_truth:
            raise ShsasError(f"--gt: survey '{p}' has no ground-truth mesh")
        return s.gt_vertices, s.gt_faces, s.meta.scene_box
    m = load_mesh(str(p))
    return m.vertices, m.faces, None


def _load_target(path: Path):
    """(points or None, mesh or None) from one file."""
    import numpy as np
    import trimesh

    if path.suffix.lower() == ".ply":
        head = path.read_bytes()[:4096]
        if b"element face" not in head or b"element face 0\n" in head:
            from shsas_core.outputs.export import read_point_cloud_points

            return read_point_cloud_points(path), None
    try:
        m = trimesh.load(path, process=False, force="mesh")
    except Exception as exc:
        raise ShsasError(f"{path}: cannot read it as a mesh ({exc})") from None
    if len(m.faces) == 0:
        return np.asarray(m.vertices), None
    return None, m


def _box_from(target: Path, box_opt: str | None, gt_box, vertices):
    import numpy as np

    from shsas_core.data.survey import SceneBox

    if box_opt:
        try:
            v = [float(x) for x in box_opt.split(",")]
            if len(v) != 6:
                raise ValueError
            return SceneBox(min=tuple(v[:3]), max=tuple(v[3:]))
        except ValueError:
            raise ShsasError(f"--box: expected six comma-separated numbers, got '{box_opt}'") from None
    if gt_box is not None:
        return gt_box
    rj = target / "report.json" if target.is_dir() else None
    if rj is not None and rj.exists():
        box = json.loads(rj.read_text()).get("survey", {}).get("scene_box_m")
        if box:
            return SceneBox(min=tuple(box["min"]), max=tuple(box["max"]))
    v = np.asarray(vertices)
    return SceneBox(min=tuple(v.min(0) - GT_BOX_MARGIN), max=tuple(v.max(0) + GT_BOX_MARGIN))


def evaluate_target(target: str | Path, gt: str, box: str | None = None) -> dict[str, dict[str, float]]:
    """``{name: {pc_*/mesh_* metric: value}}`` for an output folder or a single file."""
    from shsas_core.evaluation.metrics import GroundTruth, score_reconstruction

    target = Path(target)
    if not target.exists():
        raise ShsasError(f"target: '{target}' does not exist")
    verts, faces, gt_box = _load_gt(gt)
    sbox = _box_from(target, box, gt_box, verts)
    truth = GroundTruth(verts, faces, sbox)
    out: dict[str, dict[str, float]] = {}
    if target.is_dir():
        import trimesh

        from shsas_core.outputs.export import read_point_cloud_points

        methods = sorted({p.name.rsplit("_", 1)[0] for p in target.glob("*_pointcloud.ply")}
                         | {p.name.rsplit("_", 2)[0] for p in target.glob("*_mesh.ply")})
        if not methods:
            raise ShsasError(f"target: no *_pointcloud.ply or *_mesh.ply in '{target}'")

        for m in methods:
            pc, mesh = target / f"{m}_pointcloud.ply", target / f"{m}_mesh.ply"
            pts = None
            if pc.exists():
                pts = read_point_cloud_points(pc)
            msh = trimesh.load(mesh, process=False, force="mesh") if mesh.exists() else None
            vol = target / f"{m}_volume.npy"
            fixed = None
            if vol.exists():  # the paper's fixed level needs the volume, not the thresholded cloud
                from shsas_core.evaluation.extract import PAPER_TAU, point_cloud
                from shsas_core.outputs.export import read_volume_npy

                fixed = point_cloud(read_volume_npy(vol), PAPER_TAU).points
            out[m] = score_reconstruction(pts, msh, truth, fixed)
    else:
        pts, msh = _load_target(target)
        out[target.stem] = score_reconstruction(pts, msh, truth)
    return out


def run(args: argparse.Namespace) -> int:
    from shsas_core.evaluation.metrics import finite_or_none

    res = evaluate_target(args.target, args.gt, args.box)
    if args.write:
        if not Path(args.target).is_dir():
            raise ShsasError("--write: only for output folders")
        from shsas_core.outputs.export import write_json

        write_json({k: finite_or_none(v) for k, v in res.items()}, Path(args.target) / "evaluation.json")
    if args.json:
        print(json.dumps({k: finite_or_none(v) for k, v in res.items()}, indent=2))
        return 0
    from shsas_core.cli.reconstruct import console, metrics_table, print_warnings
    from shsas_core.evaluation.diagnostics import mesh_warnings

    console().print(metrics_table(res, title=f"evaluation of {args.target} against {args.gt}"))
    print_warnings({name: mesh_warnings(m) for name, m in res.items()})
    return 0
