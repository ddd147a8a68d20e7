"""The real AirSAS bunny's geometry: what the survey assumes, and what the image says about it.

    python benchmarks/real_bunny_geometry.py [--survey FOLDER_OR_H5] [--volume BP.npy]
        [--grid 48] [--angle-step 4] [--yaw-starts 12]

Prints JSON lines (docs/decisions/real-bunny-geometry.md reads them):

- ``geometry``: the survey's sound speed, level heights (first, step, last, the largest
  departure from an even step), range window (the two-way path of the first and last sample),
  sensor radius about the turntable axis, and the autofocus record when the survey carries one;
- ``alignment``: the backprojection's threshold cloud aligned to ``bunny.obj`` rigidly and with
  one free uniform scale: scale, yaw, tilt, shift, Chamfer-L2; and kept upright (yaw and
  shift only), since the object stands on the turntable;
- ``heights_rigid``, ``heights_upright``: under each of those two alignments, the object's vertical extent in the image against the mesh's: the highest
  voxel layer whose brightest voxel reaches the extraction threshold τ, τ/2 and τ/4, the
  cloud's extent in z and in x, y (5-95 % quantiles after the rigid alignment), mesh beside,
  and per height band of the mesh (body, head, ears) the share of its surface sample within
  5 mm and 10 mm of the rigidly aligned cloud.

``--volume`` takes an ``|image|`` saved by ``bench_real_bunny.py --save-volume`` over the same
box (its shape names the grid); otherwise the backprojection is computed here.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from shsas_core.data.geometry import height_levels
from shsas_core.data.volume import Grid, Volume
from shsas_core.evaluation.align import align_rigid
from shsas_core.evaluation.extract import choose_threshold, normalize, point_cloud
from shsas_core.evaluation.metrics import sample_surface
from shsas_core.formats import load_survey

SHARED = Path(__file__).resolve().parents[2] / "shared"
FOLDER = SHARED / "data" / "airsas" / "bunny_20k_deconvolved"
MESH = SHARED / "data" / "meshes" / "bunny.obj"
#: height bands of the mesh (m): body, head, ears (above 0.14 m the mesh is the two ears)
BANDS_M = ((0.0, 0.07), (0.07, 0.14), (0.14, 0.16), (0.16, 0.19))


def survey_geometry(s) -> dict:
    """Sound speed, level heights, range window and sensor radius of a survey (m, m/s)."""
    lv = height_levels(s.tx)
    h = lv.heights
    steps = np.diff(h)
    even = h[0] + np.median(steps) * np.arange(h.size) if h.size > 1 else h
    a = s.meta.attrs
    out = {"sound_speed_m_s": s.meta.sound_speed, "levels": int(h.size),
           "tx_height_first_m": float(h[0]), "tx_height_last_m": float(h[-1]),
           "tx_height_step_m": float(np.median(steps)) if steps.size else None,
           "tx_height_max_departure_from_even_m": float(np.max(np.abs(h - even))),
           "tx_radius_m": float(np.median(np.hypot(s.tx[:, 0], s.tx[:, 1]))),
           "rx_radius_m": float(np.median(np.hypot(s.rx[:, 0], s.rx[:, 1]))),
           "range_min_dist_m": a.get("range_min_dist_m"), "range_max_dist_m": a.get("range_max_dist_m"),
           "first_sample_path_m": float(np.median(s.t0) * s.meta.sound_speed)}
    if "autofocus" in a:
        out["autofocus"] = json.loads(a["autofocus"])
    return out


def upright_alignment(points: np.ndarray, reference: np.ndarray, yaw_step_deg: float = 10.0,
                      iterations: int = 15, max_points: int = 3000) -> tuple[float, np.ndarray, float]:
    """The object kept standing: yaw (a grid of ``yaw_step_deg``, then 2° steps about the best)
    and a shift (translation-only ICP on at most ``max_points`` points), no tilt, no scale.
    Returns (yaw °, (P, 3) moved points, symmetric Chamfer-L2 of all of them, m²)."""
    from shsas_core.evaluation.metrics import chamfer

    tree = cKDTree(reference)
    rng = np.random.default_rng(0)
    sub = points if len(points) <= max_points else points[rng.choice(len(points), max_points, replace=False)]

    def turn(deg: float) -> np.ndarray:
        a = np.deg2rad(deg)
        return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])

    def fit(deg: float) -> tuple[np.ndarray, float]:
        p = sub @ turn(deg).T
        t = reference.mean(0) - p.mean(0)
        for _ in range(iterations):
            _, i = tree.query(p + t, k=1)
            t = t + np.mean(reference[i] - (p + t), axis=0)
        d, _ = tree.query(p + t, k=1)
        return t, float(np.mean(d**2))

    coarse = {d: fit(d) for d in np.arange(0.0, 360.0, yaw_step_deg)}
    best = min(coarse, key=lambda d: coarse[d][1])
    fine = {d: fit(d) for d in best + np.arange(-yaw_step_deg + 2, yaw_step_deg - 1, 2.0)}
    deg = min(fine, key=lambda d: fine[d][1])
    moved = points @ turn(deg).T + fine[deg][0]
    return float(deg % 360.0), moved, chamfer(moved, reference)["chamfer_l2"]


def height_evidence(vol: Volume, tau: float, rigid_points: np.ndarray, gt_v: np.ndarray, gt_f: np.ndarray) -> dict:
    """The image's vertical extent against the mesh's (module docstring, ``heights``)."""
    norm = normalize(vol)
    layer_max = norm.max(axis=(0, 1))
    z = vol.grid.box_min[2] + (np.arange(norm.shape[2]) + 0.5) * vol.grid.spacing[2]

    def top(level: float) -> float | None:
        k = np.flatnonzero(layer_max >= level)
        return float(z[k[-1]]) if k.size else None

    def bottom(level: float) -> float | None:
        k = np.flatnonzero(layer_max >= level)
        return float(z[k[0]]) if k.size else None

    q = np.quantile(rigid_points, [0.05, 0.95], axis=0)
    gt = sample_surface(gt_v, gt_f)
    near = cKDTree(rigid_points).query(gt, k=1)[0]
    bands = {}
    for lo, hi in BANDS_M:
        sel = (gt[:, 2] >= lo) & (gt[:, 2] < hi)
        bands[f"{lo:.2f}-{hi:.2f}"] = {"mesh_samples": int(sel.sum()),
                                       "within_5mm": round(float(np.mean(near[sel] <= 0.005)), 3),
                                       "within_10mm": round(float(np.mean(near[sel] <= 0.010)), 3)}
    return {"mesh_recall_by_height": bands,"voxel_m": [float(x) for x in vol.grid.spacing],
            "layer_span_at_tau_m": [bottom(tau), top(tau)],
            "layer_span_at_half_tau_m": [bottom(tau / 2), top(tau / 2)],
            "layer_span_at_quarter_tau_m": [bottom(tau / 4), top(tau / 4)],
            "layer_max_profile": [round(float(v), 3) for v in layer_max],
            "cloud_z_extent_m": float(np.ptp(rigid_points[:, 2])),
            "cloud_q05_q95_m": [[round(float(v), 4) for v in r] for r in q],
            "mesh_z_extent_m": float(np.ptp(gt_v[:, 2])),
            "mesh_q05_q95_m": [[round(float(v), 4) for v in r] for r in np.quantile(gt, [0.05, 0.95], axis=0)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--survey", default=str(FOLDER))
    ap.add_argument("--volume", default=None, help="|image| .npy over the survey's box")
    ap.add_argument("--grid", type=int, default=48)
    ap.add_argument("--angle-step", type=int, default=4)
    ap.add_argument("--yaw-starts", type=int, default=12)
    args = ap.parse_args()
    import trimesh

    s = load_survey(args.survey, load_samples=args.volume is None)
    print(json.dumps({"geometry": survey_geometry(s)}), flush=True)
    if args.volume:
        values = np.load(args.volume).astype(np.float32)
        grid = Grid.over(s.meta.scene_box, max(values.shape))
        if tuple(grid.shape) != values.shape:
            raise SystemExit(f"{args.volume}: shape {values.shape} is not the grid {grid.shape} over the box")
    else:
        from shsas_core.imaging.backprojection import backproject_survey

        per = int(s.meta.attrs.get("pings_per_level", 360))
        idx = np.arange(s.num_pings).reshape(-1, per)[:, :: args.angle_step].ravel()
        sub = s.subset(idx)
        grid = Grid.over(sub.meta.scene_box, args.grid)
        values = np.abs(backproject_survey(sub, grid, sub.samples).values).astype(np.float32)
    vol = Volume(grid, values, name="backprojection")
    mesh = trimesh.load(MESH, force="mesh")
    gt_v, gt_f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    gt = sample_surface(gt_v, gt_f)
    tau = choose_threshold(vol)
    pts = point_cloud(vol, tau).points
    from trimesh.registration import icp

    from shsas_core.evaluation.align import Alignment
    from shsas_core.evaluation.metrics import chamfer

    rigid = align_rigid(pts, gt, yaw_starts=args.yaw_starts)
    # the scale is refined from the best rigid pose (one more ICP, not one per start)
    m, _, _ = icp(pts, gt, initial=rigid.matrix, threshold=1e-9, max_iterations=60, reflection=False,
                  translation=True, scale=True)
    moved = pts @ m[:3, :3].T + m[:3, 3]
    c = chamfer(moved, gt)
    scaled = Alignment(m, moved, c["chamfer_l2"], c["chamfer_l1"], rigid.start_yaw_deg)
    out = {name: {**{k: round(v, 5) for k, v in a.pose().items()}, "chamfer_l2": a.chamfer_l2,
                  "matrix": np.round(a.matrix, 6).tolist()}
           for name, a in (("rigid", rigid), ("scaled", scaled))}
    yaw, standing, c_up = upright_alignment(pts, gt)
    out["upright"] = {"yaw_deg": yaw, "tilt_deg": 0.0, "scale": 1.0, "chamfer_l2": c_up}
    print(json.dumps({"alignment": out, "tau": tau, "points": len(pts), "start_yaw_deg": rigid.start_yaw_deg}),
          flush=True)
    print(json.dumps({"heights_rigid": height_evidence(vol, tau, rigid.points, gt_v, gt_f)}), flush=True)
    print(json.dumps({"heights_upright": height_evidence(vol, tau, standing, gt_v, gt_f)}), flush=True)


if __name__ == "__main__":
    main()
