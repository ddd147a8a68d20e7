// The result of one succeeded job: 3-D view with layer toggles and the iso-level slider
// (GET .../extract re-extracts from the saved volume), metrics from report.json, the MIPs
// from report.html, the survey plot, and every artifact.

import { api } from "./api.js";
import { drawCurve, elapsed, jobTitle, timeLeft } from "./jobs.js";
import { LogView } from "./joblog.js";
import { methodName, plainStage } from "./stages.js";
import { layerColour, Viewer, viridisGradient } from "./viewer.js";
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
    this.log = new LogView($("log-box"), $("log-lines"), $("log-count"));
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
    const active = ["queued", "running"].includes(job.status);
    this.log.show(job.id, active);
    if (job.status !== "succeeded") {
      // reachable by its address at any time; the result appears here once it succeeded
      $("result-body").hidden = true;
      this.job = null;
      $("result-state").textContent = active
        ? `This job is ${job.status}; its result appears here when it has finished.`
        : `This job ${job.status === "failed" ? "failed" : "was cancelled"}; it has no result.${job.error ? ` ${job.error}` : ""}`;
      if (active) {
        this.waitingFor = job.id;
        this.live(job);
      } else $("result-live").hidden = true;
      return;
    }
    $("result-state").textContent = "";
    $("result-live").hidden = true;
    this.pair = null;
    $("job-extras").hidden = false;
    $("one-job-tools").hidden = false;
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

  /** The open job's live status while it is queued or running: stage, progress, elapsed time,
   *  time left, the loss curve (``losses``: the values the list has seen) and its warnings. */
  live(job, losses = []) {
    if (this.waitingFor !== job.id) return;
    $("result-live").hidden = false;
    const bar = $("live-progress");
    bar.value = job.progress;
    bar.hidden = job.status !== "running";
    const loss = job.live_metrics?.loss;
    const parts = job.status === "running"
      ? [plainStage(job.stage), `${Math.round(job.progress * 100)} %`, elapsed(job), timeLeft(job),
        Number.isFinite(loss) ? `loss ${loss.toPrecision(3)}` : ""]
      : [elapsed(job), Number.isInteger(job.queue_position) ? `${job.queue_position} ahead in the queue` : ""];
    $("live-text").textContent = parts.filter(Boolean).join(" · ");
    $("live-text").dataset.eta = Number.isFinite(job.eta_s) ? String(job.eta_s) : "";
    // the values this page read, or, after a reload, the longer history the job's log keeps
    const curve = losses.length >= this.log.losses.length ? losses : this.log.losses;
    drawCurve($("live-loss"), job.status === "running" ? curve : []);
    $("live-warn").textContent = (job.warnings || []).map((w) => `⚠ ${methodName(w.method)}: ${w.message}`).join("\n");
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
    this.log.close();
    $("result-live").hidden = true;
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
    $("metrics-note").textContent = "";
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
  file(m, kind, job = this.job) {
    const full = kind === "mesh" ? m.artifacts.mesh_glb : m.artifacts.pointcloud;
    const preview = kind === "mesh" ? `${m.method}_mesh_preview.glb` : `${m.method}_pointcloud_preview.ply`;
    const has = job.artifacts.some((a) => a.name === preview);
    return `/reconstructions/${job.id}/artifacts/${!this.full && has ? preview : full}`;
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
      this.addToggle(`${m.method} mesh`, true, null, m.method);
      this.addToggle(`${m.method} points`, false, () => this.fetchBuffer(this.file(m, "points"))
        .then((b) => gen === this.gen && this.viewer.addPoints(`${m.method} points`, b)));
    }
    if (truth) {
      await this.viewer.addMesh("ground truth", await truth, survey.ground_truth_origin_offset, "ground_truth");
      this.addToggle("ground truth", true, null, "ground_truth");
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
    const panes = this.report.methods.slice(0, 4).map((m) => ({
      caption: methodLabel(m), name: m.method,
      layers: [{ name: `${m.method} mesh`, url: this.file(m, "mesh"), offset: m.origin_offset, colour: m.method }],
      survey: this.survey,
    }));
    await this.drawPanes(panes, gen, this.job.id);
  }

  /** ``specs`` side by side ([{caption, name, layers: [{name, url, offset, colour}], survey}]),
   *  the survey's ground truth in each, one camera for all; ``ready`` marks the body when drawn. */
  async drawPanes(specs, gen, ready) {
    this.closeCompare();
    const box = $("compare-panes");
    box.dataset.panes = String(specs.length);
    const origin = specs[0]?.layers[0]?.offset;
    const panes = specs.map((p) => {
      const fig = document.createElement("figure");
      const canvas = Object.assign(document.createElement("canvas"), { tabIndex: 0 });
      canvas.setAttribute("aria-label", `3-D view of ${p.name}: drag or arrow keys to orbit, wheel to zoom; all panes move together`);
      fig.append(canvas, Object.assign(document.createElement("figcaption"), { textContent: p.caption }));
      box.append(fig);
      const v = new Viewer(canvas, { main: false });
      v.setOrigin(origin); // one frame for all panes, so one camera shows each the same way
      return v;
    });
    this.panes = panes;
    for (const [i, p] of specs.entries()) {
      for (const layer of p.layers) {
        const mesh = await this.fetchBuffer(layer.url);
        if (gen !== this.gen || this.panes !== panes) return;
        await panes[i].addMesh(layer.name, mesh, layer.offset, layer.colour);
      }
      if (p.survey?.ground_truth_url) {
        const gt = await this.fetchBuffer(p.survey.ground_truth_url);
        if (gen !== this.gen || this.panes !== panes) return;
        await panes[i].addMesh("ground truth", gt, p.survey.ground_truth_origin_offset, "ground_truth");
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
    document.body.dataset.compareReady = ready; // for tests: every pane is drawn
  }

  /** Two jobs side by side (#/compare/{a}/{b}): one pane each with all its methods, one camera,
   *  and one metrics table with the rows of both. */
  async showPair(ids, { focus = false } = {}) {
    this.gen = (this.gen || 0) + 1;
    const gen = this.gen;
    this.waitingFor = null;
    this.log.close();
    $("result-hint").hidden = true;
    $("result-live").hidden = true;
    $("result-state").textContent = "";
    $("result-h").textContent = "Two jobs side by side";
    if (focus) this.bringIntoView();
    const jobs = await Promise.all(ids.map((id) => api(`/reconstructions/${id}`)));
    if (gen !== this.gen) return;
    $("result-h").textContent = `${jobTitle(jobs[0])} beside ${jobTitle(jobs[1])}`;
    const unfinished = jobs.filter((j) => j.status !== "succeeded");
    if (unfinished.length) {
      $("result-body").hidden = true;
      $("result-state").textContent = unfinished.map((j) => `${jobTitle(j)} is ${j.status}: it has no result to compare.`).join(" ");
      return;
    }
    const [reports, surveys] = await Promise.all([
      Promise.all(jobs.map((j) => api(`/reconstructions/${j.id}/artifacts/report.json`))),
      Promise.all(jobs.map((j) => api(`/reconstructions/${j.id}/survey`).catch(() => null))),
    ]);
    if (gen !== this.gen) return;
    this.job = null; // a single job opened next loads afresh
    this.loaded = false;
    this.full = false;
    this.buffers = new Map();
    this.loading = { done: 0, total: 0, bytes: 0 };
    this.pair = jobs;
    this.viewer.clear();
    $("result-body").hidden = false;
    $("single-view").hidden = true;
    $("compare").hidden = false;
    $("job-extras").hidden = true; // MIPs, survey and files belong to one job: each has its page
    $("one-job-tools").hidden = true;
    $("full-res").hidden = true;
    $("metrics-note").textContent = "";
    jobs.forEach((j, i) => this.renderMetrics(reports[i], j, i > 0));
    const warnings = jobs.flatMap((j) => (j.warnings || []).map((w) => ({ ...w, method: `${jobTitle(j)}: ${methodName(w.method)}` })));
    this.renderWarnings({ warnings });
    const panes = jobs.map((j, i) => ({
      caption: `${jobTitle(j)} — ${reports[i].methods.map((m) => methodName(m.method)).join(", ")}`, name: jobTitle(j),
      layers: reports[i].methods.map((m) => ({ name: `${m.method} mesh`, url: this.file(m, "mesh", j), offset: m.origin_offset, colour: m.method })),
      survey: surveys[i],
    }));
    await this.drawPanes(panes, gen, jobs.map((j) => j.id).join(","));
  }

  closeCompare() {
    for (const v of this.panes || []) v.dispose();
    this.panes = [];
    $("compare-panes").replaceChildren();
    delete document.body.dataset.compareReady;
  }

  /** A layer's checkbox; ``load`` fetches a layer that is not in the scene yet when first ticked. */
  addToggle(name, on, load = null, colourKey = null) {
    const id = `layer-${name.replace(/\W+/g, "-")}`;
    const cb = Object.assign(document.createElement("input"), { type: "checkbox", id, checked: on });
    cb.addEventListener("change", async () => {
      if (cb.checked && load && !this.viewer.layers.has(name)) await load();
      this.viewer.show(name, cb.checked);
      this.syncLegend();
    });
    this.viewer.show(name, on);
    const label = document.createElement("label");
    label.htmlFor = id;
    // the layer's colour beside its name: the toggles are the legend of the meshes
    const swatch = Object.assign(document.createElement("span"), { className: "swatch" });
    swatch.setAttribute("aria-hidden", "true");
    if (colourKey) swatch.style.background = layerColour(colourKey);
    else swatch.style.background = viridisGradient(); // a cloud: coloured by its intensity
    if (colourKey === "ground_truth") swatch.style.opacity = "0.5";
    swatch.dataset.colour = colourKey ? layerColour(colourKey) : "intensity";
    label.append(cb, swatch, ` ${name}`);
    $("layers").append(label);
    this.syncLegend();
  }

  /** The intensity scale shows while a point cloud is drawn: its colours run from τ to 1. */
  syncLegend() {
    const clouds = [...$("layers").querySelectorAll("input:checked")].some((cb) => cb.id.endsWith("-points"));
    $("cloud-legend").hidden = !clouds;
    $("cloud-legend-bar").style.background = viridisGradient();
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
      this.updateMetrics(info);
      const line = this.status(info);
      $("iso-status").textContent = line;
      $("iso-status").dataset.points = String(info.points);
      $("iso-status").dataset.tau = String(info.threshold);
    } catch (e) {
      $("iso-status").textContent = "";
      this.onError(e, true);
    }
  }

  /** One row per method of ``report`` (of ``job``, named in the row when two jobs are shown). */
  renderMetrics(report, job = null, append = false) {
    const table = $("metrics");
    const head = `<thead><tr><th scope="col">method</th>${METRIC_COLUMNS.map((c) => `<th scope="col">${c}</th>`).join("")}</tr></thead>`;
    const rows = report.methods.map((m) => {
      const all = { ...m.metrics, threshold: m.threshold, points: m.points, faces: m.faces, seconds: m.seconds };
      const cells = METRIC_COLUMNS.map((c) => `<td data-metric="${c}" data-value="${all[c] ?? ""}">${fmt(all[c])}</td>`).join("");
      const name = job ? `${escape(jobTitle(job))}: ${m.method}` : m.method;
      return `<tr data-method="${m.method}"${job ? ` data-job="${job.id}"` : ""}><th scope="row">${name}</th>${cells}</tr>`;
    });
    if (!append || !table.tBodies.length) table.innerHTML = `${head}<tbody>${rows.join("")}</tbody>`;
    else table.tBodies[0].insertAdjacentHTML("beforeend", rows.join(""));
  }

  /** The row of ``method`` after a re-extraction: its level, counts and (with ground truth) scores. */
  updateMetrics(info) {
    const row = $("metrics").querySelector(`tr[data-method="${info.method}"]`);
    if (!row) return;
    const all = { ...(info.metrics || {}), threshold: info.threshold, points: info.points, faces: info.faces };
    for (const td of row.querySelectorAll("td[data-metric]")) {
      const c = td.dataset.metric;
      if (c === "seconds") continue; // the job's time, not the extraction's
      const v = all[c] ?? (info.metrics ? null : undefined);
      if (v === undefined) continue; // no ground truth: its scores stay those of the job's level
      td.textContent = fmt(v);
      td.dataset.value = v ?? "";
    }
    row.dataset.tau = String(info.threshold);
    $("metrics-note").textContent = info.metrics && "pc_surface_f1" in info.metrics
      ? `${info.method}: scores at τ = ${fmt(info.threshold)} (re-extracted)`
      : `${info.method}: counts at τ = ${fmt(info.threshold)}; the survey has no ground truth to score against`;
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
