"""The run report: ``report.json`` (validated by :class:`Report`) and a self-contained
``report.html`` a person opens in a browser.

The HTML embeds every figure as a base64 PNG (one file, nothing to lose when it is downloaded
from the service): maximum-intensity projections of each method's volume along x, y and z,
rendered views of the extracted meshes beside the ground truth, loss curves of the neural
methods, measured vs. predicted signals for a few pings, and the metrics table. A method whose
result looks failed (:mod:`shsas_core.evaluation.diagnostics`) gets a red box at the top of the page.
"""

from __future__ import annotations

import base64
import dataclasses
import datetime as _dt
import html
import io
import math
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from shsas_core import __version__
from shsas_core.data.volume import Volume
from shsas_core.evaluation.diagnostics import ResultWarning
from shsas_core.spec.job import ReconstructionSpec

REPORT_SCHEMA_VERSION = 1

METRICS_PROTOCOL = (
    "metrics protocol (shsas_core/evaluation/metrics.py, surfaces): GT surface sample 20,000 area-weighted points (seed 0). "
    "surface_* (primary): IoU/precision/recall/F1 on 5 mm voxels over the scene box, a voxel belonging to a "
    "surface when its centre is within 5 mm of it (GT: the mesh surface; prediction: a point, or the mesh "
    "surface), no fill. fscore / fscore_2_5mm: F-score at 5 mm / 2.5 mm on points. Chamfer-L2 = sum of the "
    "two mean squared NN distances (m²); Chamfer-L1 = mean of the two unsquared means (m). solid_* "
    "(secondary, the paper code's convention): GT voxels inside or within one voxel of the surface, "
    "predicted voxels holding a point / mesh sample. Mesh quality: pieces (connected components holding "
    "95 % of the area), area_ratio (mesh / GT area), normal_consistency (mean |n·n_gt| at nearest points, "
    "both ways). pc_* = thresholded point cloud (τ by the extraction rule), fixed_* = point cloud at the "
    "paper's fixed level τ = 0.2, mesh_* = the extracted mesh."
)

#: The scored outputs of a method, in table order: (metric key prefix, label).
OUTPUT_ROWS: list[tuple[str, str]] = [("pc", "point cloud"), ("fixed", "point cloud, τ = 0.2"), ("mesh", "mesh")]

#: Metrics shown in the HTML table and the CLI, in this order (key, header, format): the primary
#: surface F1 first, the paper code's solid F1 after the point scores, then the mesh's quality.
TABLE_COLUMNS: list[tuple[str, str, str]] = [
    ("surface_f1", "surface F1", "{:.3f}"),
    ("fscore", "F@5mm", "{:.3f}"),
    ("fscore_2_5mm", "F@2.5mm", "{:.3f}"),
    ("chamfer_l2", "Chamfer-L2 (m²)", "{:.3e}"),
    ("chamfer_l1", "Chamfer-L1 (m)", "{:.3e}"),
    ("solid_f1", "solid F1 (paper code)", "{:.3f}"),
    ("pieces", "pieces", "{:.0f}"),
    ("area_ratio", "area ratio", "{:.2f}"),
    ("normal_consistency", "normal cons.", "{:.3f}"),
]


class MethodReport(BaseModel):
    """What one method produced."""

    model_config = ConfigDict(extra="forbid")

    method: str
    sh_degree: int | None = Field(None, description="SH degree L of neural methods")
    threshold: float = Field(description="normalised iso level τ used for extraction")
    points: int = Field(ge=0, description="points in the point cloud")
    faces: int = Field(ge=0, description="triangles in the mesh")
    seconds: float = Field(ge=0, description="wall time of this method (fit/backprojection + extraction)")
    metrics: dict[str, float | None] = Field(default_factory=dict, description="pc_*, fixed_* and mesh_* metrics "
                                             "(METRICS_PROTOCOL); mesh_pieces also without ground truth; None = undefined")
    signal_errors: dict[str, float] = Field(default_factory=dict, description="novel-view transient errors")
    loss_curve: list[tuple[int, float]] = Field(default_factory=list, description="(iteration, loss)")
    artifacts: dict[str, str] = Field(default_factory=dict, description="kind -> file name in out_dir")
    origin_offset: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0],
                                       description="GLB coordinates + offset = survey frame, m")
    # default empty: done.json files written before the checks existed still load
    warnings: list[ResultWarning] = Field(default_factory=list,
                                          description="signs that this result failed (shsas_core.evaluation.diagnostics)")


class Report(BaseModel):
    """Contents of ``report.json``."""

    model_config = ConfigDict(extra="forbid")

    schema_version: int = REPORT_SCHEMA_VERSION
    shsas_version: str = __version__
    created_utc: str = Field(default_factory=lambda: _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))
    spec: ReconstructionSpec
    survey: dict[str, Any] = Field(description="shsas_core.formats.hdf5.summarize of the input")
    ground_truth: bool
    metrics_protocol: str = METRICS_PROTOCOL
    timings: dict[str, float] = Field(default_factory=dict, description="seconds per stage")
    # None in reports written before it was recorded (they still load)
    device: str | None = Field(None, description="the torch device that ran the job: cpu or cuda:N (card)")
    methods: list[MethodReport] = Field(default_factory=list)
    artifacts: list[str] = Field(default_factory=list, description="file names in out_dir")

    def metrics(self) -> dict[str, dict[str, float | None]]:
        """``{method: {metric: value}}``; an undefined value is None, as in report.json, the
        pipeline's result, the job table and the API (one form end to end)."""
        return {m.method: {k: (None if v is None else float(v)) for k, v in m.metrics.items()}
                for m in self.methods}

    def warnings(self) -> dict[str, list[ResultWarning]]:
        """``{method: [warning, ...]}`` for every method (empty lists when nothing was found)."""
        return {m.method: list(m.warnings) for m in self.methods}


@dataclasses.dataclass
class SignalFit:
    """Measured and predicted signals of a few pings for one method.

    Attributes:
        times: (K, T) sample times, s (or range bins; labelled by ``x_label``).
        measured, predicted: (K, T) complex.
        pings: (K,) ping indices.
    """

    times: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    pings: list[int]
    x_label: str = "time (ms)"


@dataclasses.dataclass
class ReportFigures:
    """In-memory inputs of the HTML figures (everything optional)."""

    volumes: dict[str, Volume] = dataclasses.field(default_factory=dict)
    meshes: dict[str, Any] = dataclasses.field(default_factory=dict)
    gt_mesh: Any | None = None
    signal_fits: dict[str, SignalFit] = dataclasses.field(default_factory=dict)
    #: the backprojection of a single-height survey's plane of best focus, (nx, ny, 1)
    plane: Volume | None = None


# --------------------------------------------------------------------------------------------
# figures
def _png(fig: Any) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def mip_figure(volumes: dict[str, Volume]) -> bytes:
    """PNG: one row per method, maximum-intensity projections along x, y and z of the
    normalised magnitude, in survey-frame metres."""
    from shsas_core.evaluation.extract import normalize

    plt = _plt()
    names = list(volumes)
    fig, axes = plt.subplots(len(names), 3, figsize=(10, 3.1 * len(names)), squeeze=False)
    for r, name in enumerate(names):
        vol = volumes[name]
        n = normalize(vol)
        lo, hi = np.asarray(vol.grid.box_min), np.asarray(vol.grid.box_max)
        for c, (axis, (a, b)) in enumerate(zip((0, 1, 2), ((1, 2), (0, 2), (0, 1)), strict=True)):
            img = n.max(axis=axis)  # dims (a, b)
            ax = axes[r, c]
            ax.imshow(img.T, origin="lower", extent=(lo[a], hi[a], lo[b], hi[b]), cmap="magma",
                      vmin=0, vmax=1, aspect="equal")
            ax.set_xlabel("xyz"[a] + " (m)")
            ax.set_ylabel("xyz"[b] + " (m)")
            ax.set_title(f"{name}: MIP along {'xyz'[axis]}", fontsize=9)
    fig.tight_layout()
    return _png(fig)


def plane_figure(volumes: dict[str, Volume], z: float, plane: Volume | None = None) -> bytes:
    """PNG: the plane at height ``z`` (normalised magnitude) side by side: ``plane`` (its own
    backprojection, when given), then each method's slice nearest ``z`` where its grid holds
    ``z``: what a single-height survey shows instead of projections of a 3-D volume."""
    plt = _plt()
    panels: list[tuple[str, Volume, int]] = [("backprojection of the plane", plane, 0)] if plane is not None else []
    for name, vol in volumes.items():
        zs = vol.grid.axes()[2]
        k = int(np.argmin(np.abs(zs - z)))
        if abs(zs[k] - z) <= vol.grid.spacing[2]:
            panels.append((f"{name}: z = {zs[k]:.3f} m", vol, k))
    fig, axes = plt.subplots(1, max(len(panels), 1), figsize=(3.6 * max(len(panels), 1), 3.6), squeeze=False)
    for c, (title, vol, k) in enumerate(panels):
        img = np.abs(np.asarray(vol.values)[:, :, k])
        peak = float(img.max())
        img = img / peak if peak > 0 else img
        lo, hi = np.asarray(vol.grid.box_min), np.asarray(vol.grid.box_max)
        ax = axes[0, c]
        ax.imshow(img.T, origin="lower", extent=(lo[0], hi[0], lo[1], hi[1]), cmap="magma", vmin=0, vmax=1,
                  aspect="equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return _png(fig)


def focus_figure(focus: dict[str, Any], box_z: tuple[float, float] | None = None) -> bytes:
    """PNG: the focus measure against height (``planar.FocusResult.summary()``), the chosen
    plane marked and the scene box's height shaded."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 2.8))
    ax.plot(focus["heights_m"], focus["costs"], lw=1.0, marker=".", ms=3)
    if box_z is not None:
        ax.axvspan(*box_z, color="0.85", zorder=0, label="scene box")
    ax.axvline(focus["z_m"], color="C3" if focus["found"] else "0.4", ls="-" if focus["found"] else ":",
               label=("plane of best focus" if focus["found"] else "sharpest plane (search edge: no focus)"))
    ax.set_xlabel("plane height z (m)")
    ax.set_ylabel(f"{focus['measure']} (lower = sharper)" if focus["measure"] == "entropy"
                  else f"{focus['measure']} cost (lower = sharper)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _png(fig)


def mesh_figure(meshes: dict[str, Any], gt_mesh: Any | None = None, max_faces: int = 20000) -> bytes:
    """PNG: each mesh (and the ground truth) from the same oblique viewpoint, shaded by normal."""
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    items = ([("ground truth", gt_mesh)] if gt_mesh is not None else []) + list(meshes.items())
    fig = plt.figure(figsize=(3.4 * len(items), 3.6))
    allv = [np.asarray(m.vertices) for _, m in items if len(m.faces)]
    if allv:
        v = np.concatenate(allv)
        lo, hi = v.min(0), v.max(0)
    else:
        lo, hi = np.zeros(3), np.ones(3)
    if gt_mesh is not None and len(gt_mesh.faces):
        lo, hi = np.asarray(gt_mesh.vertices).min(0), np.asarray(gt_mesh.vertices).max(0)
        pad = 0.25 * (hi - lo)
        lo, hi = lo - pad, hi + pad
    light = np.array([0.4, -0.5, 0.8]) / np.linalg.norm([0.4, -0.5, 0.8])
    for i, (name, m) in enumerate(items):
        ax = fig.add_subplot(1, len(items), i + 1, projection="3d")
        f = np.asarray(m.faces)
        if len(f):
            if len(f) > max_faces:  # keep the figure quick; an even stride keeps coverage uniform
                f = f[:: math.ceil(len(f) / max_faces)]
            tri = np.asarray(m.vertices)[f]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True) + 1e-30
            shade = 0.25 + 0.75 * np.clip(nrm @ light, 0, 1)
            col = np.stack([shade * 0.55, shade * 0.75, shade * 0.95, np.ones_like(shade)], 1)
            ax.add_collection3d(Poly3DCollection(tri, facecolors=col, edgecolors="none"))
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(tuple(np.maximum(hi - lo, 1e-9)))
        ax.view_init(elev=20, azim=-60)
        ax.set_title(f"{name} ({len(m.faces)} faces)", fontsize=9)
        ax.tick_params(labelsize=6)
    return _png(fig)


def loss_figure(curves: dict[str, list[tuple[int, float]]]) -> bytes:
    """PNG: training loss against iteration (log scale) for each neural method."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.4))
    for name, curve in curves.items():
        if curve:
            it, loss = zip(*curve, strict=True)
            ax.plot(it, loss, label=name)
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.legend()
    ax.grid(alpha=0.3)
    return _png(fig)


def signal_figure(fits: dict[str, SignalFit]) -> bytes:
    """PNG: |measured| and |predicted| signal per ping (rows: pings, columns: methods)."""
    plt = _plt()
    names = list(fits)
    k = max(len(f.pings) for f in fits.values())
    fig, axes = plt.subplots(k, len(names), figsize=(4.2 * len(names), 2.2 * k), squeeze=False)
    for c, name in enumerate(names):
        fit = fits[name]
        for r in range(len(fit.pings)):
            ax = axes[r, c]
            t = np.asarray(fit.times[r])
            ax.plot(t, np.abs(fit.measured[r]), lw=0.8, label="measured |s_PD|")
            ax.plot(t, np.abs(fit.predicted[r]), lw=0.8, label="rendered |ŝ|")
            ax.set_title(f"{name}, ping {fit.pings[r]}", fontsize=9)
            ax.set_xlabel(fit.x_label, fontsize=8)
            ax.tick_params(labelsize=7)
            if r == 0 and c == 0:
                ax.legend(fontsize=7)
    return _png(fig)


# --------------------------------------------------------------------------------------------
# HTML
def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}">'


def _fmt(v: float | None, fmt: str) -> str:
    if v is None or not math.isfinite(v):
        return "–"
    return fmt.format(v)


def metrics_table_html(report: Report) -> str:
    rows = []
    for m in report.methods:
        for rep, label in OUTPUT_ROWS:
            if not any(k.startswith(rep + "_") for k in m.metrics):
                continue
            cells = "".join(f"<td>{_fmt(m.metrics.get(f'{rep}_{k}'), f)}</td>" for k, _, f in TABLE_COLUMNS)
            rows.append(f"<tr><td>{html.escape(m.method)}</td><td>{label}</td>{cells}</tr>")
    head = "".join(f"<th>{html.escape(h)}</th>" for _, h, _ in TABLE_COLUMNS)
    return f"<table><tr><th>method</th><th>output</th>{head}</tr>{''.join(rows)}</table>"


def warnings_html(report: Report) -> str:
    """One coloured box per method with warnings (empty string when there are none)."""
    esc = html.escape
    boxes = []
    for m in report.methods:
        if not m.warnings:
            continue
        items = "".join(f"<li><b>{esc(w.code)}</b>: {esc(w.message)} (measure {w.measure:.3g}, "
                        f"limit {w.limit:.3g})</li>" for w in m.warnings)
        what = ("its mesh is not one clean surface" if all(w.code.startswith("mesh_") for w in m.warnings)
                else "this result looks failed")
        boxes.append(f"<div class='warn'><b>{esc(m.method)}: {what}</b><ul>{items}</ul></div>")
    survey_warnings = [str(w) for w in report.survey.get("warnings") or []]
    if survey_warnings:
        items = "".join(f"<li>{esc(w)}</li>" for w in survey_warnings)
        boxes.insert(0, f"<div class='warn'><b>survey</b><ul>{items}</ul></div>")
    if not boxes:
        return ""
    return ("<h2>Warnings</h2>" + "".join(boxes)
            + "<p><small>Checks and limits: docs/usage.md, “Warnings”.</small></p>")


def focus_html(report: Report, figures: ReportFigures, focus: dict[str, Any]) -> str:
    """The plane-of-focus section of a single-height survey's report: the plane (or why there
    is none), the measure along height, and the object's size with the range resolution."""
    esc = html.escape
    box = report.survey.get("scene_box_m") or {}
    box_z = (box["min"][2], box["max"][2]) if box else None
    lo, hi = focus["search_range_m"]
    res_mm = 1e3 * focus["range_resolution_m"]
    search = (f"searched from z = {lo:.3f} m (as far below the scene box's floor as the lowest sensor stands "
              f"above it, and no deeper than the recording reaches) to {hi:.3f} m (the lowest sensor), by "
              f"{esc(focus['measure'])} of backprojected planes")
    curve = _img(focus_figure(focus, box_z), "focus measure along height")
    if not focus["found"]:
        return (f"<h2>No plane of focus found</h2><p>{esc(str(focus['reason']))}</p><p>{search}. The "
                "projections below are a 3-D volume's; read them with care.</p>" + curve)
    z = focus["z_m"]
    out = [f"<h2>Plane of best focus (z = {z:.3f} m)</h2><p>The sharpest horizontal plane, {search}: "
           "lowest over height. Each image below is that plane.</p>",
           _img(plane_figure(figures.volumes, z, figures.plane), "plane"), curve]
    o = (report.survey.get("elevation") or {}).get("outline")
    if o:
        ex, ey = (1e3 * v for v in o["extent_m"])
        out.append(f"<p>Object in this plane: <b>{ex:.0f} mm × {ey:.0f} mm</b> (x × y, between its "
                   f"edges' half-maximum points) at range resolution c / 2B = <b>{res_mm:.1f} mm</b>: "
                   "each edge is blurred over about that much, so sizes read off this image are "
                   "uncertain by about one range resolution.</p>")
    return "".join(out)


def render_html(report: Report, figures: ReportFigures) -> str:
    """The report page: summary, metrics, figures. Images are embedded as base64 PNG."""
    esc = html.escape
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>shsas report</title><style>",
        "body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px}",
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
        "text-align:right}th{background:#eee}img{max-width:100%;display:block;margin:0.5em 0}"
        "code{background:#f4f4f4}"
        ".warn{background:#fdecea;border:2px solid #d93025;border-radius:4px;padding:0.5em 1em;"
        "margin:0.5em 0}",
        "</style></head><body>",
        f"<h1>shsas reconstruction report</h1><p>shsas {esc(report.shsas_version)}, "
        f"{esc(report.created_utc)}" + (f", on {esc(report.device)}" if report.device else "") + "</p>",
        # first thing after the title: a failed result must not pass for a good one
        warnings_html(report),
        "<h2>Survey</h2><table>",
    ]
    for k in ("platform", "pings", "samples_per_ping", "band_hz", "sound_speed_m_s", "range_resolution_m"):
        if k in report.survey:
            parts.append(f"<tr><th>{esc(k)}</th><td>{esc(str(report.survey[k]))}</td></tr>")
    parts.append("</table>")
    # an autofocused survey says what was corrected and what the data could not identify
    verdict = (report.survey.get("attrs") or {}).get("autofocus_summary")
    if verdict:
        parts.append(f"<p class='note'>{esc(str(verdict))}</p>")
    parts.append("<h2>Spec</h2><pre>" + esc(report.spec.model_dump_json(indent=1)) + "</pre>")
    parts.append("<h2>Methods</h2><table><tr><th>method</th><th>L</th><th>τ</th><th>points</th>"
                 "<th>faces</th><th>seconds</th><th>warnings</th><th>files</th></tr>")
    for m in report.methods:
        files = " ".join(f"<a href='{esc(v)}'>{esc(k)}</a>" for k, v in m.artifacts.items())
        warn = ", ".join(esc(w.code) for w in m.warnings) or "none"
        parts.append(f"<tr><td>{esc(m.method)}</td><td>{'' if m.sh_degree is None else m.sh_degree}</td>"
                     f"<td>{m.threshold:.3f}</td><td>{m.points}</td><td>{m.faces}</td>"
                     f"<td>{m.seconds:.1f}</td><td>{warn}</td><td>{files}</td></tr>")
    parts.append("</table>")
    if report.ground_truth and any(m.metrics for m in report.methods):
        parts.append("<h2>Metrics</h2>" + metrics_table_html(report))
        parts.append(f"<p><small>{esc(report.metrics_protocol)}</small></p>")
    else:
        parts.append("<h2>Metrics</h2><p>The survey has no ground truth; no geometry metrics.</p>")
    elev = report.survey.get("elevation") or {}
    if elev.get("kind", "3d") != "3d":
        parts.append(f"<h2>Elevation</h2><p class='note'>{esc(str(elev.get('message', '')))}</p>")
    focus = elev.get("focus")
    if focus is not None and elev.get("kind", "3d") != "3d":
        parts.append(focus_html(report, figures, focus))
    if figures.volumes and not (focus and focus["found"]):
        parts.append("<h2>Maximum-intensity projections</h2>" + _img(mip_figure(figures.volumes), "MIP"))
    if figures.meshes:
        parts.append("<h2>Meshes</h2>" + _img(mesh_figure(figures.meshes, figures.gt_mesh), "meshes"))
    curves = {m.method: m.loss_curve for m in report.methods if m.loss_curve}
    if curves:
        parts.append("<h2>Training loss</h2>" + _img(loss_figure(curves), "loss curves"))
    if figures.signal_fits:
        parts.append("<h2>Signal fits</h2>" + _img(signal_figure(figures.signal_fits), "signal fits"))
    errs = {m.method: m.signal_errors for m in report.methods if m.signal_errors}
    if errs:
        keys = sorted({k for e in errs.values() for k in e})
        parts.append("<h3>Novel-view signal errors</h3><table><tr><th>method</th>"
                     + "".join(f"<th>{esc(k)}</th>" for k in keys) + "</tr>")
        for name, e in errs.items():
            parts.append(f"<tr><td>{esc(name)}</td>" + "".join(f"<td>{_fmt(e.get(k), '{:.3e}')}</td>" for k in keys) + "</tr>")
        parts.append("</table>")
    if report.timings:
        parts.append("<h2>Timings (s)</h2><table>" + "".join(
            f"<tr><th>{esc(k)}</th><td>{v:.2f}</td></tr>" for k, v in report.timings.items()) + "</table>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(report: Report, figures: ReportFigures, out_dir: Any,
                 json_name: str = "report.json", html_name: str = "report.html") -> tuple[str, str]:
    """Write ``report.json`` and ``report.html`` atomically into ``out_dir``; return both paths."""
    from pathlib import Path

    from shsas_core.outputs.export import write_text

    out = Path(out_dir)
    jp = write_text(report.model_dump_json(indent=2), out / json_name)
    hp = write_text(render_html(report, figures), out / html_name)
    return str(jp), str(hp)


def load_report(path: Any) -> Report:
    """Read and validate a ``report.json``."""
    from pathlib import Path

    return Report.model_validate_json(Path(path).read_text())
