// The result of one succeeded job: 3-D view with layer toggles and the iso-level slider
// (GET .../extract re-extracts from the saved volume), metrics from report.json, the MIPs
// from report.html, the survey plot, and every artifact.

import { api } from "./api.js";
import { jobTitle } from "./jobs.js";
import { methodName } from "./stages.js";
import { Viewer } from "./viewer.js";
import { plotPings, plotSurvey } from "./survey.js";

// the primary surface F1 first (shsas_core/evaluation/metrics.py), then the mesh's quality
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

function methodLabel(m) {
  const f = m.metrics?.pc_fscore;
  return `${methodName(m.method)}${Number.isFinite(f) ? ` — F-score ${f.toFixed(3)}` : ""}`;
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
    $("full-res").addEventListener("click", () => this.loadFull().catch((e) => this.onError(e, true)));
  }

  /** Show job ``id`` (the route #/jobs/{id}); ``focus``: bring it into view and move focus there. */
  async show(id, { compare = false, focus = false } = {}) {
    this.gen = (this.gen || 0) + 1;
    const gen = this.gen;
    this.waitingFor = null;
    $("result-hint").hidden = true;
    $("result-h").textContent = `Result of ${id.slice(0, 8)}`;
    if (focus) this.bringIntoView();
    const job = await api(`/reconstructions/${id}`);
    if (gen !== this.gen) return;
    $("result-h").textContent = `Result of ${jobTitle(job)}`;
    if (job.status !== "succeeded") {
      // reachable by its address at any time; the result appears here once it succeeded
      $("result-body").hidden = true;
      this.job = null;
      $("result-state").textContent = ["queued", "running"].includes(job.status)
        ? `This job is ${job.status}; its result appears here when it has finished.`
        : `This job ${job.status === "failed" ? "failed" : "was cancelled"}; it has no result.${job.error ? ` ${job.error}` : ""}`;
      if (["queued", "running"].includes(job.status)) this.waitingFor = job.id;
      return;
    }
    $("result-state").textContent = "";
    this.setMode(job, compare);
    if (!(this.job?.id === job.id && this.loaded)) await this.open(job, gen);
    if (gen !== this.gen) return;
    if (compare) await this.compare(gen);
    else this.closeCompare();
  }

  /** The tabs (each an address) and which of the two views shows. */
  setMode(job, compare) {
    $("tab-view").href = `#/jobs/${job.id}`;
    $("tab-compare").href = `#/jobs/${job.id}/compare`;
    $("tab-view").setAttribute("aria-current", compare ? "false" : "page");
    $("tab-compare").setAttribute("aria-current", compare ? "page" : "false");
    $("tab-compare").hidden = (job.spec.methods || []).length < 2;
    $("single-view").hidden = compare;
    $("compare").hidden = !compare;
  }

  bringIntoView() {
    // the heading, not the 3-D view, takes the focus: a screen reader starts at the title
    $("result").scrollIntoView({ block: "start" });
    $("result-h").focus({ preventScroll: true });
  }

  close() {
    this.gen = (this.gen || 0) + 1;
    this.job = null;
    this.loaded = false;
    this.waitingFor = null;
    this.viewer.clear();
    this.closeCompare();
    $("result-body").hidden = true;
    $("result-hint").hidden = false;
    $("result-state").textContent = "";
    $("result-h").textContent = "Result";
    delete document.body.dataset.viewerReady;
  }

  async open(job, gen) {
    delete document.body.dataset.viewerReady;
    this.job = job;
    this.loaded = false;
    this.full = false;
    this.buffers = new Map();
    this.loading = { done: 0, total: 0, bytes: 0 };
    $("result-body").hidden = false;
    $("report-frame").hidden = true;
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
    this.renderWarnings(job);
    this.renderMip(base);
    if (survey) this.renderSurvey(survey);
    const methods = report.methods.map((m) => m.method);
    $("iso-method").replaceChildren(...methods.map((m) => new Option(m, m)));
    this.syncSlider();
    this.survey = survey;
    await this.loadLayers(gen);
  }

  /** The file to draw for ``kind`` ("mesh" | "points") of method entry ``m``: the light preview
   *  the worker wrote, when the job has one and full resolution was not asked for. */
  file(m, kind) {
    const full = kind === "mesh" ? m.artifacts.mesh_glb : m.artifacts.pointcloud;
    const preview = kind === "mesh" ? `${m.method}_mesh_preview.glb` : `${m.method}_pointcloud_preview.ply`;
    const has = this.job.artifacts.some((a) => a.name === preview);
    return `/reconstructions/${this.job.id}/artifacts/${!this.full && has ? preview : full}`;
  }

  /** Fetch once per job (the panes of the compare view share the files), counting progress. */
  async fetchBuffer(url) {
    if (!this.buffers.has(url)) {
      this.loading.total += 1;
      this.showLoading();
      this.buffers.set(url, buffer(url).then((b) => {
        this.loading.done += 1;
        this.loading.bytes += b.byteLength;
        this.showLoading();
        return b;
      }));
    }
    return this.buffers.get(url);
  }

  showLoading() {
    const { done, total, bytes } = this.loading;
    const bar = $("load-progress");
    bar.hidden = done >= total;
    bar.max = Math.max(total, 1);
    bar.value = done;
    $("load-status").textContent = done >= total ? "" : `loading ${done} of ${total} files (${(bytes / 1e6).toFixed(1)} MB so far)…`;
  }

  /** Every method's mesh (its points load when they are switched on) and the ground truth. */
  async loadLayers(gen) {
    const { report, survey } = this;
    const base = `/reconstructions/${this.job.id}`;
    this.viewer.clear();
    $("layers").replaceChildren(Object.assign(document.createElement("legend"), { textContent: "Show" }));
    // all files asked for at once: the browser fetches them in parallel
    const meshes = report.methods.map((m) => this.fetchBuffer(this.file(m, "mesh")));
    const truth = survey?.ground_truth_url ? this.fetchBuffer(survey.ground_truth_url) : null;
    for (const [i, m] of report.methods.entries()) {
      const mesh = await meshes[i];
      if (gen !== this.gen) return;
      await this.viewer.addMesh(`${m.method} mesh`, mesh, m.origin_offset, m.method);
      this.addToggle(`${m.method} mesh`, true);
      this.addToggle(`${m.method} points`, false, () => this.fetchBuffer(this.file(m, "points"))
        .then((b) => gen === this.gen && this.viewer.addPoints(`${m.method} points`, b)));
    }
    if (truth) {
      await this.viewer.addMesh("ground truth", await truth, survey.ground_truth_origin_offset, "ground_truth");
      this.addToggle("ground truth", true);
    }
    if (gen !== this.gen) return;
    this.viewer.frame();
    const previews = report.methods.some((m) => !this.file(m, "mesh").endsWith(m.artifacts.mesh_glb));
    $("full-res").hidden = !previews;
    $("iso-status").textContent = this.status(report.methods.find((m) => m.method === $("iso-method").value)) +
      (previews ? " (shown: the light preview)" : "");
    this.loaded = true;
    document.body.dataset.viewerReady = this.job.id; // for tests: every layer is in the scene
  }

  /** The full-resolution meshes and clouds in place of the previews. */
  async loadFull() {
    this.full = true;
    $("full-res").hidden = true;
    await this.loadLayers(this.gen);
    if (!$("compare").hidden) await this.compare(this.gen);
  }

  /** The methods side by side, one pane each (at most four), with one camera for all. */
  async compare(gen) {
    this.closeCompare();
    const methods = this.report.methods.slice(0, 4);
    const box = $("compare-panes");
    box.dataset.panes = String(methods.length);
    const origin = methods[0]?.origin_offset;
    const panes = methods.map((m) => {
      const fig = document.createElement("figure");
      const canvas = Object.assign(document.createElement("canvas"), { tabIndex: 0 });
      canvas.setAttribute("aria-label", `3-D view of ${m.method}: drag or arrow keys to orbit, wheel to zoom; all panes move together`);
      fig.append(canvas, Object.assign(document.createElement("figcaption"), { textContent: methodLabel(m) }));
      box.append(fig);
      const v = new Viewer(canvas, { main: false });
      v.setOrigin(origin); // one frame for all panes, so one camera shows each the same way
      return v;
    });
    this.panes = panes;
    for (const [i, m] of methods.entries()) {
      const mesh = await this.fetchBuffer(this.file(m, "mesh"));
      if (gen !== this.gen || this.panes !== panes) return;
      await panes[i].addMesh(`${m.method} mesh`, mesh, m.origin_offset, m.method);
      if (this.survey?.ground_truth_url) {
        const gt = await this.fetchBuffer(this.survey.ground_truth_url);
        await panes[i].addMesh("ground truth", gt, this.survey.ground_truth_origin_offset, "ground_truth");
      }
    }
    if (gen !== this.gen || this.panes !== panes) return;
    const all = panes[0].box();
    for (const v of panes.slice(1)) all.union(v.box());
    for (const v of panes) {
      v.resize();
      v.frameBox(all);
    }
    Viewer.link(panes);
    document.body.dataset.compareReady = this.job.id; // for tests: every pane is drawn
  }

  closeCompare() {
    for (const v of this.panes || []) v.dispose();
    this.panes = [];
    $("compare-panes").replaceChildren();
    delete document.body.dataset.compareReady;
  }

  /** A layer's checkbox; ``load`` fetches a layer that is not in the scene yet when first ticked. */
  addToggle(name, on, load = null) {
    const id = `layer-${name.replace(/\W+/g, "-")}`;
    const cb = Object.assign(document.createElement("input"), { type: "checkbox", id, checked: on });
    cb.addEventListener("change", async () => {
      if (cb.checked && load && !this.viewer.layers.has(name)) await load();
      this.viewer.show(name, cb.checked);
    });
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
      this.viewer.show(`${method} points`, !!$(`layer-${method}-points`)?.checked); // as its box says
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

  /** The pipeline's signs that a method's result failed, above the views. */
  renderWarnings(job) {
    const box = $("result-warnings");
    box.replaceChildren();
    const ws = job.warnings || [];
    box.hidden = ws.length === 0;
    if (!ws.length) return;
    const ul = document.createElement("ul");
    for (const w of ws) ul.append(Object.assign(document.createElement("li"), { textContent: `${methodName(w.method)}: ${w.message}` }));
    box.append(Object.assign(document.createElement("strong"), { textContent: "This result may have failed:" }), ul);
  }

  renderArtifacts(job) {
    const all = $("download-all");
    all.onclick = (ev) => {
      ev.preventDefault(); // the hash is the result's address; the zip comes through fetch, with the key
      this.download({ name: "results.zip", url: `/reconstructions/${job.id}/artifacts.zip` }).catch((e) => this.onError(e, true));
    };
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
      // shown in a sandboxed frame: a report is made from user data and must not run script here.
      // A new frame each time: Chromium leaves a frame whose srcdoc was replaced while it was
      // hidden unpainted (a blank white box although its document is there).
      const html = await api(a.url, { as: "text" });
      const old = $("report-frame");
      const frame = Object.assign(document.createElement("iframe"), { id: old.id, title: old.title, srcdoc: html });
      frame.setAttribute("sandbox", "");
      old.replaceWith(frame);
      frame.scrollIntoView({ block: "nearest" });
      frame.focus();
      return;
    }
    const blob = await api(a.url, { as: "blob" });
    const url = URL.createObjectURL(blob);
    // saved under the uploaded survey's name, as the server's Content-Disposition says
    const stem = (this.job?.input?.filename || "").replace(/^.*[\\/]/, "").replace(/\.[^.]*$/, "").trim();
    const tmp = Object.assign(document.createElement("a"), { href: url, download: stem ? `${stem}_${a.name}` : a.name });
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
