// The result of one succeeded job: 3-D view with layer toggles and the iso-level slider
// (GET .../extract re-extracts from the saved volume), metrics from report.json, the MIPs
// from report.html, the survey plot, and every artifact.

import { api } from "./api.js";
import { plotPings, plotSurvey } from "./survey.js";

// the primary surface F1 first (shsas_core/metrics.py), then the mesh's quality
const METRIC_COLUMNS = ["threshold", "points", "faces", "seconds", "pc_surface_f1", "pc_fscore", "pc_chamfer_l2",
  "mesh_surface_f1", "mesh_fscore", "mesh_chamfer_l2", "mesh_pieces", "mesh_area_ratio", "mesh_normal_consistency"];

const $ = (id) => document.getElementById(id);

function fmt(v) {
  if (v === null || v === undefined) return "–";
  if (Number.isInteger(v)) return String(v);
  return Math.abs(v) >= 1e-3 && Math.abs(v) < 1e4 ? v.toPrecision(4) : v.toExponential(3);
}

async function buffer(url) {
  return api(url, { as: "buffer" });
}

export class ResultView {
  constructor(viewer, onError) {
    this.viewer = viewer;
    this.onError = onError;
    this.job = null;
    this.isoTimer = null;
    $("iso").addEventListener("input", () => {
      $("iso-value").textContent = Number($("iso").value).toFixed(2);
      clearTimeout(this.isoTimer);
      this.isoTimer = setTimeout(() => this.reextract(), 250); // one request per pause of the slider
    });
    $("iso-method").addEventListener("change", () => this.syncSlider());
  }

  async open(job) {
    this.job = job;
    this.gen = (this.gen || 0) + 1;
    const gen = this.gen;
    $("result-body").hidden = false;
    $("result-hint").hidden = true;
    $("report-frame").hidden = true;
    $("report-frame").srcdoc = "";
    $("result-h").textContent = `Result of ${job.id.slice(0, 8)}`;
    this.viewer.resize();
    this.viewer.clear();
    $("layers").replaceChildren(Object.assign(document.createElement("legend"), { textContent: "Show" }));
    $("iso-status").textContent = "loading…";
    const base = `/reconstructions/${job.id}`;
    const [report, survey] = await Promise.all([
      api(`${base}/artifacts/report.json`),
      api(`${base}/survey`).catch((e) => (this.onError(e, true), null)),
    ]);
    if (gen !== this.gen) return;
    this.report = report;
    this.renderMetrics(report);
    this.renderArtifacts(job);
    this.renderMip(base);
    if (survey) this.renderSurvey(survey);
    const methods = report.methods.map((m) => m.method);
    $("iso-method").replaceChildren(...methods.map((m) => new Option(m, m)));
    this.syncSlider();
    for (const m of report.methods) {
      const mesh = await buffer(`${base}/artifacts/${m.artifacts.mesh_glb}`);
      if (gen !== this.gen) return;
      await this.viewer.addMesh(`${m.method} mesh`, mesh, m.origin_offset, m.method);
      this.viewer.addPoints(`${m.method} points`, await buffer(`${base}/artifacts/${m.artifacts.pointcloud}`));
      this.addToggle(`${m.method} mesh`, true);
      this.addToggle(`${m.method} points`, false);
    }
    if (survey?.ground_truth_url) {
      await this.viewer.addMesh("ground truth", await buffer(survey.ground_truth_url), survey.ground_truth_origin_offset, "ground_truth");
      this.addToggle("ground truth", true);
    }
    if (gen !== this.gen) return;
    this.viewer.frame();
    $("iso-status").textContent = this.status(report.methods.find((m) => m.method === $("iso-method").value));
    document.body.dataset.viewerReady = job.id; // for tests: every layer is in the scene
  }

  addToggle(name, on) {
    const id = `layer-${name.replace(/\W+/g, "-")}`;
    const cb = Object.assign(document.createElement("input"), { type: "checkbox", id, checked: on });
    cb.addEventListener("change", () => this.viewer.show(name, cb.checked));
    this.viewer.show(name, on);
    const label = document.createElement("label");
    label.htmlFor = id;
    label.append(cb, ` ${name}`);
    $("layers").append(label);
  }

  syncSlider() {
    const m = this.report?.methods.find((r) => r.method === $("iso-method").value);
    if (!m) return;
    $("iso").value = m.threshold.toFixed(2);
    $("iso-value").textContent = Number($("iso").value).toFixed(2);
  }

  status(info) {
    return info ? `${info.method} at τ = ${fmt(info.threshold)}: ${info.points} points, ${info.faces} triangles` : "";
  }

  async reextract() {
    const method = $("iso-method").value;
    const tau = Number($("iso").value);
    const base = `/reconstructions/${this.job.id}`;
    const seq = (this.isoSeq = (this.isoSeq || 0) + 1);
    $("iso-status").textContent = `re-extracting ${method} at τ = ${tau.toFixed(2)}…`;
    try {
      const info = await api(`${base}/extract?method=${encodeURIComponent(method)}&threshold=${tau}`);
      const [mesh, pts] = await Promise.all([buffer(info.mesh_url), buffer(info.pointcloud_url)]);
      if (seq !== this.isoSeq) return; // the slider moved on: a later answer is coming
      await this.viewer.addMesh(`${method} mesh`, mesh, info.origin_offset, method);
      this.viewer.addPoints(`${method} points`, pts);
      const line = this.status(info);
      $("iso-status").textContent = line;
      $("iso-status").dataset.points = String(info.points);
      $("iso-status").dataset.tau = String(info.threshold);
    } catch (e) {
      $("iso-status").textContent = "";
      this.onError(e, true);
    }
  }

  renderMetrics(report) {
    const table = $("metrics");
    const head = `<thead><tr><th scope="col">method</th>${METRIC_COLUMNS.map((c) => `<th scope="col">${c}</th>`).join("")}</tr></thead>`;
    const rows = report.methods.map((m) => {
      const all = { ...m.metrics, threshold: m.threshold, points: m.points, faces: m.faces, seconds: m.seconds };
      const cells = METRIC_COLUMNS.map((c) => `<td data-metric="${c}" data-value="${all[c] ?? ""}">${fmt(all[c])}</td>`).join("");
      return `<tr data-method="${m.method}"><th scope="row">${m.method}</th>${cells}</tr>`;
    });
    table.innerHTML = `${head}<tbody>${rows.join("")}</tbody>`;
  }

  renderArtifacts(job) {
    const list = $("artifacts");
    list.replaceChildren();
    for (const a of job.artifacts) {
      const li = document.createElement("li");
      const link = Object.assign(document.createElement("a"), { href: a.url, textContent: a.name });
      link.addEventListener("click", (ev) => {
        ev.preventDefault(); // plain links cannot carry the key: fetch, then hand over a blob
        this.download(a).catch((e) => this.onError(e, true));
      });
      li.append(link);
      list.append(li);
    }
  }

  async download(a) {
    if (a.name.endsWith(".html")) {
      // shown in a sandboxed frame: a report is made from user data and must not run script here
      const frame = $("report-frame");
      frame.srcdoc = await api(a.url, { as: "text" });
      frame.hidden = false;
      frame.focus();
      return;
    }
    const blob = await api(a.url, { as: "blob" });
    const url = URL.createObjectURL(blob);
    const tmp = Object.assign(document.createElement("a"), { href: url, download: a.name });
    document.body.append(tmp);
    tmp.click();
    tmp.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  }

  async renderMip(base) {
    const box = $("mip");
    box.replaceChildren();
    try {
      const html = await api(`${base}/artifacts/report.html`, { as: "text" });
      // parsed, not run: only the embedded PNG (a data: URI) is taken out of the report
      const doc = new DOMParser().parseFromString(html, "text/html");
      const img = doc.querySelector('img[alt="MIP"]');
      if (img && img.getAttribute("src").startsWith("data:image/png;base64,")) {
        box.append(Object.assign(new Image(), { src: img.getAttribute("src"), alt: "maximum-intensity projections of each method's volume" }));
      } else box.textContent = "report.html has no MIP figure.";
    } catch (e) {
      box.textContent = `MIPs unavailable: ${e.message}`;
    }
  }

  renderSurvey(view) {
    plotSurvey($("survey-plot"), view);
    plotPings($("ping-plot"), view);
    const s = { ...view.summary };
    delete s.attrs;
    const rows = Object.entries(s).map(([k, v]) => `<tr><th scope="row">${k}</th><td style="text-align:left">${escape(typeof v === "object" ? JSON.stringify(v) : String(v))}</td></tr>`);
    $("survey-summary").innerHTML = `<table>${rows.join("")}</table>`;
  }
}

function escape(s) {
  return s.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}
